"""The emulated PLC program: mode transitions, source gating, watchdog, clamping."""
import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_plc import protocol as P
from quadrivio_sim.actuators import LowLevelControl, load_actuators
from quadrivio_sim.paths import package_file
from quadrivio_sim.plc_emulator import PlcLogic, PlcParams


@pytest.fixture
def plc():
    v = load_vehicle()
    ctl = LowLevelControl(load_actuators(package_file("config", "actuators.yaml")), v, 0.01)
    return PlcLogic(PlcParams(), ctl)


@pytest.mark.parametrize("start,target,ok", [
    (P.MODE_SAFE, P.MODE_AUTO, True), (P.MODE_SAFE, P.MODE_MANUAL, True), (P.MODE_SAFE, P.MODE_ASSISTED, True),
    (P.MODE_SAFE, P.MODE_HALT, True), (P.MODE_HALT, P.MODE_AUTO, False), (P.MODE_HALT, P.MODE_SAFE, True),
    (P.MODE_AUTO, P.MODE_MANUAL, True), (P.MODE_AUTO, P.MODE_SAFE, True), (P.MODE_AUTO, P.MODE_HALT, True),
    (P.MODE_SAFE, 17, False),
])
def test_transitions(plc, start, target, ok):
    plc.mode = start
    status = plc.request_mode(target)
    assert (status == P.OK) == ok
    assert plc.mode == (target if ok else start)


def test_setpoints_only_from_matching_source(plc):
    assert plc.setpoint(P.SOURCE_AUTO, 1.0, 0.1, 0.0) == P.NOT_ACCEPTING  # SAFE
    plc.request_mode(P.MODE_AUTO)
    assert plc.setpoint(P.SOURCE_MANUAL, 2.0, 0.2, 0.0) == P.WRONG_SOURCE
    assert plc.sp_speed == 0.0
    assert plc.setpoint(P.SOURCE_AUTO, 1.0, 0.1, 0.0) == P.OK
    assert (plc.sp_speed, plc.sp_handlebar) == (1.0, 0.1)
    plc.request_mode(P.MODE_ASSISTED)  # handlebar from auto, speed from manual
    plc.setpoint(P.SOURCE_AUTO, 5.0, -0.2, 0.0)
    plc.setpoint(P.SOURCE_MANUAL, 0.5, 0.3, 0.1)
    assert (plc.sp_speed, plc.sp_handlebar, plc.sp_brake) == (0.5, -0.2, 0.1)


def test_watchdog_brakes_and_flags(plc):
    plc.request_mode(P.MODE_AUTO)
    plc.handle(0.0, 1, P.Setpoint(P.SOURCE_AUTO, 2.0, 0.0, 0.0))
    plc.cycle(0.15, 0.0, 0.0)
    assert plc.mode == P.MODE_AUTO
    plc.cycle(0.25, 0.0, 0.0)  # 0.25 s since the last valid frame > 0.2 s
    assert plc.mode == P.MODE_SAFE
    assert plc.faults & P.FAULT_WATCHDOG
    assert any("watchdog" in e for e in plc.pop_events())
    out = plc.cycle(0.5, 1.0, 3.0)
    assert out.brake > 0.0  # braking in SAFE
    assert plc.request_mode(P.MODE_AUTO) == P.OK
    assert not plc.faults & P.FAULT_WATCHDOG


def test_clamped_setpoint_reported(plc):
    plc.request_mode(P.MODE_AUTO)
    assert plc.setpoint(P.SOURCE_AUTO, 50.0, 0.1, 0.0) == P.CLAMPED
    assert plc.sp_speed == plc.control.vehicle.drivetrain.max_speed
    assert plc.faults & P.FAULT_SETPOINT_CLAMPED
    assert any("clamped" in e for e in plc.pop_events())
    assert plc.setpoint(P.SOURCE_AUTO, 1.0, 0.1, 0.0) == P.OK
    assert not plc.faults & P.FAULT_SETPOINT_CLAMPED


def test_non_finite_setpoint_ignored(plc):
    plc.request_mode(P.MODE_AUTO)
    plc.setpoint(P.SOURCE_AUTO, 1.0, 0.1, 0.0)
    assert plc.setpoint(P.SOURCE_AUTO, float("nan"), 0.0, 0.0) == P.BAD_VALUE
    assert plc.sp_speed == 1.0


def test_halt_freezes_handlebar(plc):
    plc.request_mode(P.MODE_AUTO)
    plc.setpoint(P.SOURCE_AUTO, 0.0, 0.3, 0.0)
    for k in range(100):
        plc.handle(k * 0.01, k, P.Heartbeat())
        plc.cycle(k * 0.01, 0.0, 0.0)
    angle = plc.control.handlebar.angle
    assert angle > 0.2
    plc.request_mode(P.MODE_HALT)
    assert plc.faults & P.FAULT_ESTOP
    for k in range(100, 150):
        out = plc.cycle(k * 0.01, 0.0, 0.0)
    assert out.handlebar == angle
    assert out.brake > 0.5
