"""The attitude filter (quadrivio_navigation.attitude): the vehicle's own acceleration is no
tilt, the slope is found, the gyro carries it through a wheel that lies."""
import math

import pytest

from quadrivio_navigation.attitude import Attitude

G = 9.80665


def feed(att, t0, t1, pitch, accel, v0, wheel=None, dt=0.01):
    """A vehicle on a slope ``pitch`` (nose down positive) accelerating at ``accel``: IMU at
    100 Hz, wheel speed at 50 Hz (``wheel(t, v)`` may lie about it)."""
    v = v0
    k = 0
    t = t0
    while t < t1 - 1e-9:
        f = (accel - G * math.sin(pitch), 0.0, G * math.cos(pitch))
        att.add_imu(t, f, (0.0, 0.0, 0.0))
        if k % 2 == 0:
            att.add_speed(t, wheel(t, v) if wheel else v)
        v += accel * dt
        t += dt
        k += 1
    return v


def test_braking_is_no_pitch_and_the_slope_is_found():
    att = Attitude(tau=1.0)
    feed(att, 0.0, 5.0, 0.0, 0.0, 3.0)
    v = feed(att, 5.0, 5.7, 0.0, -4.0, 3.0)  # a hard stop on level ground
    assert abs(att.pitch) < math.radians(1.0)  # the accelerometer alone would read 22 deg
    feed(att, 5.7, 12.0, math.radians(8), 0.0, max(v, 0.0))
    assert att.pitch == pytest.approx(math.radians(8), abs=math.radians(0.5))


def test_a_spinning_wheel_is_not_believed():
    att = Attitude(tau=1.0)
    feed(att, 0.0, 5.0, 0.0, 0.0, 0.0)
    # the wheel spins up at 20 m/s^2 while the body stands: the pull is suspended
    feed(att, 5.0, 5.3, 0.0, 0.0, 0.0, wheel=lambda t, v: 20.0 * (t - 5.0))
    assert abs(att.pitch) < math.radians(1.0)


@pytest.mark.parametrize("roll_deg, pitch_deg", [(5.0, 0.0), (-8.0, 3.0), (4.0, -6.0)])
def test_turning_while_tilted_moves_no_angle(roll_deg, pitch_deg):
    """A body held at a constant roll and pitch while it yaws at 0.6 rad/s: the gyro reads
    the yaw rate spread over its three axes (R^T (0, 0, 0.6)), and the attitude must stay
    where it is. The small-angle rates (roll' = w_x, pitch' = w_y) drifted here by
    sin(roll) 0.6 rad/s: 3 deg/s at 5 deg of roll. The gyro alone is tested (tau 1e4 s)."""
    roll, pitch, rate = math.radians(roll_deg), math.radians(pitch_deg), 0.6
    w = (-math.sin(pitch) * rate, math.sin(roll) * math.cos(pitch) * rate, math.cos(roll) * math.cos(pitch) * rate)
    f = (-G * math.sin(pitch), G * math.sin(roll) * math.cos(pitch), G * math.cos(roll) * math.cos(pitch))
    att = Attitude(tau=1e4)
    t = 0.0
    while t < 5.0:
        att.add_imu(t, f, w)
        t += 0.01
    assert att.roll == pytest.approx(roll, abs=math.radians(0.1))
    assert att.pitch == pytest.approx(pitch, abs=math.radians(0.1))
