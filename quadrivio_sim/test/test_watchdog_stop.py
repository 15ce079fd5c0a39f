"""The safety contract on the simulated vehicle: whatever a client keeps sending after its
last fresh setpoint, the PLC is in SAFE within the watchdog period plus one cycle and
the vehicle stands still within its braking time after that."""
import math

import numpy as np
import pytest

from quadrivio_config import from_mapping, load_yaml
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import load_vehicle
from quadrivio_plc import protocol as P
from quadrivio_sim.actuators import load_actuators
from quadrivio_sim.paths import package_file
from quadrivio_sim.simulator import SimParams, Simulator

SPEED = 3.0
# (Replayed frames never reach PlcLogic: the session layer drops them, test_plc_link.py.)
TRICKS = ("silence", "heartbeats", "nan setpoints", "wrong source", "mode requests")


@pytest.fixture(scope="module")
def sim():
    vehicle = load_vehicle()
    params = from_mapping(SimParams, load_yaml(package_file("config", "sim.yaml")), "sim.yaml")
    s = Simulator(params, vehicle, load_actuators(package_file("config", "actuators.yaml")), build_urdf(vehicle))
    yield s
    s.close()


def drive_then(sim, trick, seconds=4.0):
    """Drive at SPEED in AUTO through PlcLogic.handle, then play ``trick`` from the last
    fresh setpoint on; returns (t_last_fresh, t_safe, t_stopped, distance after it)."""
    sim.reset()
    plc, seq = sim.plc, [0]

    def send(msg, s=None):
        if s is None:
            seq[0] += 1
            s = seq[0]
        plc.handle(sim.t, s, msg)

    send(P.ModeRequest(P.MODE_AUTO))
    t_fresh = t_safe = t_stop = None
    x_fresh = None
    while sim.t < seconds + 6.0:
        if sim.t < seconds:
            send(P.Setpoint(P.SOURCE_AUTO, SPEED, 0.0, 0.0))
            t_fresh = sim.t
        elif trick == "heartbeats":
            send(P.Heartbeat())
        elif trick == "nan setpoints":
            send(P.Setpoint(P.SOURCE_AUTO, math.nan, 0.0, 0.0))
        elif trick == "wrong source":
            send(P.Setpoint(P.SOURCE_MANUAL, SPEED, 0.0, 0.0))
        elif trick == "mode requests":
            send(P.ModeRequest(P.MODE_AUTO))
        sim.step()
        pos, _, vel = sim.world.base_state()[:3]
        if t_fresh is not None and sim.t >= seconds and x_fresh is None:
            x_fresh = np.array(pos[:2])
        if t_safe is None and plc.mode == P.MODE_SAFE:
            t_safe = sim.t
        if t_safe is not None and t_stop is None and math.hypot(vel[0], vel[1]) < 0.05:
            t_stop = sim.t
            return t_fresh, t_safe, t_stop, float(np.linalg.norm(np.array(pos[:2]) - x_fresh))
    return t_fresh, t_safe, t_stop, math.nan


@pytest.mark.parametrize("trick", TRICKS)
def test_safe_within_the_watchdog_and_stopped_within_the_braking_distance(sim, trick):
    t_fresh, t_safe, t_stop, dist = drive_then(sim, trick)
    assert t_safe is not None, f"{trick}: still driving"
    assert t_safe - t_fresh <= sim.plc.p.watchdog + sim.plc.p.cycle + 1e-6, f"{trick}: SAFE after {t_safe - t_fresh:.3f} s"
    # Braking from 3 m/s at full brake: the vehicle's deceleration, with margin for the servo lag.
    assert t_stop is not None and t_stop - t_safe < 2.0, f"{trick}: still rolling {t_stop}"
    assert dist < SPEED * (sim.plc.p.watchdog + 0.3) + SPEED ** 2 / (2 * 3.0), f"{trick}: {dist:.2f} m"
