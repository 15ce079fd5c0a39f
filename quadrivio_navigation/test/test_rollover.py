"""Roll-over risk: tilt, lateral acceleration, thresholds, hold time (hand-worked values)."""
import math

import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_description.frames import rotate, tilt_from_gravity
from quadrivio_navigation.rollover import OK, TRIP, WARN, RolloverMonitor, RolloverParams

G = 9.81
SSF = load_vehicle().static_stability_factor  # 0.956 / (2 x 0.58) = 0.824


def settle(mon, f, w=(0.0, 0.0, 0.0), t0=0.0, seconds=3.0, dt=0.01):
    s = None
    for k in range(int(seconds / dt)):
        s = mon.update(t0 + k * dt, f, w)
    return s


def test_level_ground_is_safe():
    s = settle(RolloverMonitor(RolloverParams(), SSF), (0.0, 0.0, G))
    assert s.risk == pytest.approx(0.0) and s.roll == pytest.approx(0.0) and s.level == OK


@pytest.mark.parametrize("slope", [0.1, 0.3, 0.5])
def test_side_slope(slope):
    phi = math.atan(slope)
    s = settle(RolloverMonitor(RolloverParams(), SSF), (0.0, G * math.sin(phi), G * math.cos(phi)))
    assert s.risk == pytest.approx(slope / SSF, rel=1e-6)  # tan(phi) / SSF
    assert s.roll == pytest.approx(phi, abs=1e-6)


def test_lateral_acceleration_in_a_turn():
    # 3 m/s on a 2 m radius: 4.5 m/s^2, risk = a / (g SSF)
    s = settle(RolloverMonitor(RolloverParams(), SSF), (0.0, 4.5, G))
    assert s.risk == pytest.approx(4.5 / (G * SSF), rel=1e-6)
    assert s.lateral_accel == pytest.approx(4.5)


def test_thresholds_and_hold():
    p = RolloverParams(warn_ratio=0.6, trip_ratio=0.85, max_roll=1.0, hold_time=2.0)
    mon = RolloverMonitor(p, SSF)

    def at(ratio):  # lateral acceleration giving this fraction of tipping
        return (0.0, ratio * SSF * G, G)
    assert settle(mon, at(0.5)).level == OK
    assert settle(mon, at(0.7), t0=3.0).level == WARN
    assert settle(mon, at(0.9), t0=6.0).level == TRIP
    s = settle(mon, at(0.1), t0=9.0, seconds=1.0)  # back to safe: held for hold_time
    assert s.level == TRIP
    assert settle(mon, at(0.1), t0=10.0, seconds=2.0).level == OK


def test_tilt_beyond_max_roll_trips():
    mon = RolloverMonitor(RolloverParams(max_roll=0.4, trip_ratio=1.4, warn_ratio=1.2), SSF)
    phi = 0.45
    s = settle(mon, (0.0, G * math.sin(phi), G * math.cos(phi)))
    assert s.level == TRIP and s.roll == pytest.approx(phi, abs=1e-6)


def test_free_fall_is_not_a_tip():
    mon = RolloverMonitor(RolloverParams(), SSF)
    assert mon.update(0.0, (0.0, 0.01, 0.02), (0.0, 0.0, 0.0)).level == OK  # dropping at spawn
    assert settle(mon, (0.0, 0.0, G), t0=0.01).level == OK


def test_upside_down_trips():
    assert settle(RolloverMonitor(RolloverParams(), SSF), (0.0, 0.0, -G)).level == TRIP


def test_gyro_bridges_the_accelerometer():
    # A fast roll: the gyro leads the filtered accelerometer estimate.
    mon = RolloverMonitor(RolloverParams(tau=0.5), SSF)
    settle(mon, (0.0, 0.0, G))
    s = mon.update(mon.t + 0.1, (0.0, 0.0, G), (1.0, 0.0, 0.0))  # 1 rad/s for 0.1 s
    assert s.roll == pytest.approx(0.1 * 0.5 / 0.6, abs=1e-6)  # alpha (roll + w dt), alpha = tau / (tau + dt)


def test_mount_rotation():
    assert rotate((0.0, 0.0, math.pi / 2), (1.0, 0.0, 0.0)) == pytest.approx((0.0, 1.0, 0.0))
    assert rotate((math.pi / 2, 0.0, 0.0), (0.0, 1.0, 0.0)) == pytest.approx((0.0, 0.0, 1.0))


def test_bad_thresholds():
    with pytest.raises(ValueError, match="warn_ratio"):
        RolloverParams(warn_ratio=0.9, trip_ratio=0.8)


def test_tilt_from_gravity():
    # At rest the accelerometer reads R^T (0, 0, g): for roll r and pitch p (ZYX),
    # f = g (-sin p, cos p sin r, cos p cos r).
    roll, pitch = 0.2, -0.1
    f = (-math.sin(pitch), math.cos(pitch) * math.sin(roll), math.cos(pitch) * math.cos(roll))
    assert tilt_from_gravity(f) == pytest.approx((roll, pitch))


@pytest.mark.parametrize("bad", [(math.nan, 0.0, G), (0.0, math.inf, G), (0.0, 0.0, -math.inf)])
def test_one_non_finite_sample_does_not_latch_a_trip(bad):
    mon = RolloverMonitor(RolloverParams(), SSF)
    settle(mon, (0.0, 0.0, G))
    s = mon.update(3.0, bad, (0.0, 0.0, 0.0))
    assert s.level == OK and math.isfinite(s.risk) and mon.rejected == 1
    s = settle(mon, (0.0, 0.0, G), t0=3.01, seconds=0.5)
    assert s.level == OK and s.risk == pytest.approx(0.0, abs=1e-9)


def test_upside_down_trips_and_recovers_once_upright():
    mon = RolloverMonitor(RolloverParams(), SSF)
    assert settle(mon, (0.0, 0.0, -G), seconds=0.5).level == TRIP
    p = RolloverParams()
    s = settle(mon, (0.0, 0.0, G), t0=0.5, seconds=p.hold_time + 5.0)
    assert s.level == OK and math.isfinite(s.risk)
