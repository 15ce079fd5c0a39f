"""The simulator's round wait (quadrivio_sim.ros.lockstep_driver), without a ROS master:
reports delivered by hand, the PLC port a real emulated server on loopback."""
import json
import threading
import time

import pytest
from std_msgs.msg import String

from quadrivio_description.vehicle import load_vehicle
from quadrivio_sim.actuators import LowLevelControl, load_actuators
from quadrivio_sim.lockstep import Coordinator
from quadrivio_sim.paths import package_file
from quadrivio_sim.plc_emulator import PlcLogic, PlcParams, PlcServer
from quadrivio_sim.ros import lockstep_driver

pytestmark = pytest.mark.wall  # a round woken in time, on the wall clock (pytest.ini)


@pytest.fixture
def driver(monkeypatch):
    ctl = LowLevelControl(load_actuators(package_file("config", "actuators.yaml")), load_vehicle(), 0.01)
    server = PlcServer(PlcLogic(PlcParams(), ctl), "127.0.0.1", 0, lambda: 0.0, lambda lvl, txt: None,
                       key=b"test-key-0123456789abcdef")
    d = lockstep_driver.LockstepDriver.__new__(lockstep_driver.LockstepDriver)  # no master: the state by hand
    d.server, d.stop, d.name = server, (lambda: False), "/simulator"
    d.coord = Coordinator(["/adapter", "/loc", "/silent"], "/simulator")
    d.cond = threading.Condition()
    d.plc_base, d.left, d.errors, d.waiting = (0, 0, 0), [], 0, None
    yield d
    server.close()


def report(d, node, seq):
    d._on_report(String(data=json.dumps({"node": node, "seq": seq, "sent": {}, "error": ""})))


def test_a_round_returns_when_its_last_report_is_in(driver):
    threading.Timer(0.1, report, (driver, "/adapter", 7)).start()
    threading.Timer(0.2, report, (driver, "/loc", 7)).start()
    t0 = time.monotonic()
    assert driver._wait(["/adapter", "/loc"], 7)
    assert 0.15 < time.monotonic() - t0 < 5.0  # woken by the last report, not by a slice or a timeout
    assert driver.waiting is None and driver.left == []


def test_a_member_silent_past_the_give_up_time_leaves_and_the_round_goes_on(driver, monkeypatch):
    monkeypatch.setattr(lockstep_driver, "GIVE_UP", 0.3)
    report(driver, "/adapter", 3)
    assert driver._wait(["/adapter", "/silent"], 3)  # raised on its second pass before
    assert driver.left == ["/silent"] and driver.coord.members == ["/adapter", "/loc"]
    report(driver, "/adapter", 4)  # the next round does not wait for it
    assert driver.coord.pending(["/adapter"], 4) == []
