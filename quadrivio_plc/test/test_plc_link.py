"""PLCClient core against the emulated PLC over real loopback TCP (no ROS)."""
import socket
import threading
import time

import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_plc import protocol as P
from quadrivio_plc.client import Multiplexer, PlcLink
from quadrivio_sim.actuators import LowLevelControl, load_actuators
from quadrivio_sim.paths import package_file
from quadrivio_sim.plc_emulator import PlcLogic, PlcParams, PlcServer


class Harness:
    """An emulated PLC polled in a thread, its sim clock advanced by hand."""

    def __init__(self):
        ctl = LowLevelControl(load_actuators(package_file("config", "actuators.yaml")), load_vehicle(), 0.01)
        self.logic = PlcLogic(PlcParams(), ctl)
        self.t = 0.0
        self.log = []
        self.server = PlcServer(self.logic, "127.0.0.1", 0, lambda: self.t, lambda lvl, txt: self.log.append(txt))
        self.port = self.server.address[1]
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self):
        while not self.stop.is_set():
            self.server.poll(0.01)

    def close(self):
        self.stop.set()
        self.thread.join()
        self.server.close()


@pytest.fixture
def plc():
    h = Harness()
    yield h
    h.close()


def wait(cond, timeout=5.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def make_link(port, **kw):
    link = PlcLink("127.0.0.1", port, reconnect_min=0.05, reconnect_max=0.2, **kw)
    stop = threading.Event()

    def run():
        while not stop.is_set():
            link.poll(0.01)
    th = threading.Thread(target=run, daemon=True)
    th.start()
    return link, stop, th


def test_mode_setpoint_and_state(plc):
    states, acks = [], []
    link, stop, th = make_link(plc.port, on_state=states.append, on_ack=acks.append)
    try:
        wait(lambda: link.connected)
        done = threading.Event()
        answer = []
        link.send(P.ModeRequest(P.MODE_AUTO), on_ack=lambda a: (answer.append(a), done.set()))
        assert done.wait(2.0)
        assert answer[0].status == P.OK and answer[0].mode == P.MODE_AUTO
        link.send(P.Setpoint(P.SOURCE_AUTO, 2.0, 0.1, 0.0))
        wait(lambda: plc.logic.sp_speed == pytest.approx(2.0))
        assert plc.logic.sp_handlebar == pytest.approx(0.1)
        plc.server.send_state(plc.logic.state(0.5, 1.23))
        wait(lambda: states)
        assert states[-1].mode == P.MODE_AUTO and states[-1].wheel_speed == pytest.approx(1.23)
        p50, p99 = link.rtt_percentiles(50, 99)
        assert 0.0 < p50 <= p99 < 0.1
        assert link.stats.lost_frames == 0
    finally:
        stop.set()
        th.join()
        link.close()


def test_second_client_refused_with_reason(plc):
    link, stop, th = make_link(plc.port)
    try:
        wait(lambda: link.connected)
        with socket.create_connection(("127.0.0.1", plc.port), timeout=2) as s2:
            s2.settimeout(2.0)
            data = b""
            while True:
                chunk = s2.recv(4096)
                if not chunk:
                    break
                data += chunk
        [(_, msg)] = P.FrameDecoder().feed(data)
        assert isinstance(msg, P.Refused) and msg.reason == P.BUSY
        assert "another client" in msg.text
        assert link.connected and plc.server.refused == 1
    finally:
        stop.set()
        th.join()
        link.close()


def test_garbage_is_counted_and_the_plc_keeps_working(plc):
    with socket.create_connection(("127.0.0.1", plc.port), timeout=2) as s:
        s.sendall(b"\x00\xffQV\x01garbage" + P.encode(P.ModeRequest(P.MODE_AUTO), 0)[:-1] + b"\x00")
        s.sendall(b"QV" + bytes(200))
        s.sendall(P.encode(P.ModeRequest(P.MODE_AUTO), 1))
        s.settimeout(2.0)
        dec = P.FrameDecoder()
        got = []
        while not got:
            got = dec.feed(s.recv(4096))
        assert isinstance(got[0][1], P.Ack) and got[0][1].ack_seq == 1 and got[0][1].status == P.OK
    wait(lambda: plc.server.decoder.stats.bad_frames >= 2)
    assert plc.logic.mode == P.MODE_AUTO
    assert any("rejected" in line for line in plc.log)


def test_reconnects_after_plc_restart():
    h = Harness()
    port = h.port
    link, stop, th = make_link(port)
    try:
        wait(lambda: link.connected)
        h.close()
        wait(lambda: not link.connected)
        h2_logic = Harness.__new__(Harness)
        # A new PLC on the same port: the link comes back by itself.
        ctl = LowLevelControl(load_actuators(package_file("config", "actuators.yaml")), load_vehicle(), 0.01)
        h2_logic.logic = PlcLogic(PlcParams(), ctl)
        h2_logic.t = 0.0
        h2_logic.log = []
        h2_logic.server = PlcServer(h2_logic.logic, "127.0.0.1", port, lambda: 0.0, lambda *a: None)
        h2_logic.stop = threading.Event()
        h2_logic.thread = threading.Thread(target=h2_logic._run, daemon=True)
        h2_logic.thread.start()
        wait(lambda: link.connected, timeout=5.0)
        assert link.stats.connects == 2 and link.stats.disconnects == 1
        h2_logic.close()
    finally:
        stop.set()
        th.join()
        link.close()


def test_connect_failure_backs_off():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]  # nobody listens here
    t = [0.0]
    link = PlcLink("127.0.0.1", port, reconnect_min=0.1, reconnect_max=0.4, clock=lambda: t[0])
    delays = []
    for _ in range(5):
        link.poll(0.0)
        delays.append(link.next_attempt - t[0])
        t[0] = link.next_attempt
    assert delays == pytest.approx([0.1, 0.2, 0.4, 0.4, 0.4])
    assert "cannot connect" in link.last_error


def test_multiplexer_by_mode_and_staleness():
    mux = Multiplexer(timeout=0.25, stop_brake=0.5)
    mux.update(P.SOURCE_AUTO, 10.0, 2.0, 0.1, 0.0)
    mux.update(P.SOURCE_MANUAL, 10.0, 1.0, -0.2, 0.3)
    assert mux.frames(P.MODE_AUTO, 10.1) == [P.Setpoint(P.SOURCE_AUTO, 2.0, 0.1, 0.0)]
    assert mux.frames(P.MODE_MANUAL, 10.1) == [P.Setpoint(P.SOURCE_MANUAL, 1.0, -0.2, 0.3)]
    assert mux.frames(P.MODE_ASSISTED, 10.1) == [P.Setpoint(P.SOURCE_AUTO, 2.0, 0.1, 0.0),
                                                 P.Setpoint(P.SOURCE_MANUAL, 1.0, -0.2, 0.3)]
    assert mux.frames(P.MODE_SAFE, 10.1) == [P.Heartbeat()]
    # Stale autonomous setpoint: a stop, handlebar held at the last value.
    assert mux.frames(P.MODE_AUTO, 10.5) == [P.Setpoint(P.SOURCE_AUTO, 0.0, 0.1, 0.5)]
    assert mux.stale[P.SOURCE_AUTO]
    assert mux.accepts(P.MODE_AUTO, P.SOURCE_AUTO) and not mux.accepts(P.MODE_AUTO, P.SOURCE_MANUAL)
