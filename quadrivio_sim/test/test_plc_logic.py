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
    assert plc.request_mode(P.MODE_AUTO) == P.BAD_TRANSITION  # still moving: finish braking first
    assert any("still moving" in e for e in plc.pop_events())
    plc.cycle(0.6, 0.05, 0.1)
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
    for k in range(100):
        plc.handle(k * 0.01, k, P.Setpoint(P.SOURCE_AUTO, 0.0, 0.3, 0.0))
        plc.cycle(k * 0.01, 0.0, 0.0)
    angle = plc.control.handlebar.angle
    assert angle > 0.2
    plc.request_mode(P.MODE_HALT)
    assert plc.faults & P.FAULT_ESTOP
    for k in range(100, 150):
        out = plc.cycle(k * 0.01, 0.0, 0.0)
    assert out.handlebar == angle
    assert out.brake > 0.5


# ---------------------------------------------------------------- the safety contract
def _drive(plc, t0=0.0, source=P.SOURCE_AUTO, mode=P.MODE_AUTO):
    assert plc.request_mode(mode, t0) == P.OK
    assert plc.handle(t0, 1, P.Setpoint(source, 2.0, 0.1, 0.0)).status == P.OK


def _safe_after(plc, feed, t_last_fresh=0.0, horizon=1.0):
    """Run PLC cycles while ``feed(t)`` sends frames; the time SAFE was reached (None: never)."""
    k = 1
    while k * 0.01 <= horizon + 1e-9:
        t = t_last_fresh + k * 0.01
        feed(t)
        plc.cycle(t, 1.0, 3.0)
        if plc.mode == P.MODE_SAFE:
            return t
        k += 1
    return None


@pytest.mark.parametrize("trick", ["heartbeats", "nan setpoints", "wrong source", "mode requests",
                                   "refused mode requests", "inf setpoints"])
def test_only_fresh_setpoints_of_the_modes_source_feed_the_watchdog(plc, trick):
    _drive(plc)
    seq = [10]

    def feed(t):
        seq[0] += 1
        msg = {"heartbeats": P.Heartbeat(),
               "nan setpoints": P.Setpoint(P.SOURCE_AUTO, float("nan"), 0.0, 0.0),
               "inf setpoints": P.Setpoint(P.SOURCE_AUTO, 1.0, float("inf"), 0.0),
               "wrong source": P.Setpoint(P.SOURCE_MANUAL, 2.0, 0.1, 0.0),
               "mode requests": P.ModeRequest(P.MODE_AUTO),
               "refused mode requests": P.ModeRequest(P.MODE_SAFE + 40)}[trick]
        plc.handle(t, seq[0], msg)

    t_safe = _safe_after(plc, feed)
    assert t_safe is not None and t_safe <= plc.p.watchdog + 0.0101, f"{trick} kept AUTO until {t_safe}"
    assert plc.faults & P.FAULT_WATCHDOG
    assert plc.sp_speed == 0.0 and plc.state(t_safe, 0.0).setpoint_speed == 0.0  # nothing left of AUTO


def test_fresh_setpoints_keep_driving(plc):
    _drive(plc)
    seq = [10]

    def feed(t):
        seq[0] += 1
        plc.handle(t, seq[0], P.Setpoint(P.SOURCE_AUTO, 2.0, 0.1, 0.0))

    assert _safe_after(plc, feed, horizon=2.0) is None and plc.mode == P.MODE_AUTO


def test_assisted_needs_both_sources_fresh(plc):
    assert plc.request_mode(P.MODE_ASSISTED, 0.0) == P.OK
    seq = [0]

    def feed(t):  # the safety driver's speed only: the handlebar source is silent
        seq[0] += 1
        plc.handle(t, seq[0], P.Setpoint(P.SOURCE_MANUAL, 1.0, 0.0, 0.0))

    t_safe = _safe_after(plc, feed)
    assert t_safe is not None and t_safe <= plc.p.watchdog + 0.0101


def test_a_mode_change_between_driving_modes_never_feeds_the_watchdog(plc):
    _drive(plc)  # the last fresh setpoint at t = 0
    plc.cycle(0.15, 0.0, 0.0)
    assert plc.request_mode(P.MODE_MANUAL, 0.15) == P.OK
    plc.cycle(0.21, 0.0, 0.0)
    assert plc.mode == P.MODE_SAFE


def test_link_loss_brakes_and_is_reported(plc):
    _drive(plc)
    plc.link_lost(0.05, "connection reset")
    assert plc.mode == P.MODE_SAFE and plc.faults & P.FAULT_LINK
    assert plc.sp_speed == 0.0 and plc.sp_brake == plc.p.hold_brake
    assert plc.cycle(0.06, 1.0, 3.0).brake >= 0.0 and plc.mode == P.MODE_SAFE
    plc.cycle(0.9, 0.0, 0.0)
    assert plc.request_mode(P.MODE_AUTO, 1.0) == P.OK  # a new session's request clears it
    assert not plc.faults & P.FAULT_LINK


def test_halt_is_not_left_by_a_link_loss(plc):
    plc.request_mode(P.MODE_HALT)
    plc.link_lost(0.0, "closed")
    assert plc.mode == P.MODE_HALT and not plc.faults & P.FAULT_LINK
