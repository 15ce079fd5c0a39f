"""The attitude filter (quadrivio_description.attitude): the vehicle's own acceleration is no
tilt, the slope is found, the gyro carries it through a wheel that lies."""
import math

import pytest

from quadrivio_description.attitude import Attitude

G = 9.80665


def feed(att, t0, t1, pitch, accel, v0, wheel=None, dt=0.01, rate=0.0, gyro_bias=0.0):
    """A vehicle on a slope ``pitch`` (nose down positive; changing at ``rate`` [rad/s])
    accelerating at ``accel``: IMU at 100 Hz (its y gyro off by ``gyro_bias``), wheel speed
    at 50 Hz (``wheel(t, v)`` may lie about it). Returns the speed (and the pitch)."""
    v = v0
    k = 0
    t = t0
    while t < t1 - 1e-9:
        f = (accel - G * math.sin(pitch), 0.0, G * math.cos(pitch))
        att.add_imu(t, f, (0.0, rate + gyro_bias, 0.0))
        pitch += rate * dt
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
    feed(att, 5.7, 6.7, 0.0, 0.0, max(v, 0.0), rate=math.radians(8))  # onto an 8 deg slope in 1 s
    assert att.pitch == pytest.approx(math.radians(8), abs=math.radians(0.5))
    feed(att, 6.7, 12.0, math.radians(8), 0.0, max(v, 0.0))
    assert att.pitch == pytest.approx(math.radians(8), abs=math.radians(0.1))


def test_the_gyros_bias_is_learnt():
    """A y gyro 3e-3 rad/s off (a MEMS gyro's turn-on bias): a proportional pull alone holds
    the pitch bias x tau off (0.69 deg at 4 s); the integral learns the bias."""
    att = Attitude(tau=4.0)
    feed(att, 0.0, 90.0, math.radians(3), 0.0, 2.0, gyro_bias=3e-3)
    assert att.pitch == pytest.approx(math.radians(3), abs=math.radians(0.05))
    assert att.bias_pitch == pytest.approx(3e-3, rel=0.05)


def test_the_imus_lever_arm_is_no_tilt():
    """A steady turn on level ground, 3 m/s at 0.6 rad/s, the IMU 0.55 m ahead of base_link
    and 0.25 m up: on top of base_link's own v w_z to the left its accelerometer feels the
    centripetal -r w_z^2 (0.2 m/s^2 backward: 1.1 deg of nose-down tilt to the accelerometer). With the lever
    taken out the attitude stays level."""
    r, v, wz = (0.55, 0.0, 0.25), 3.0, 0.6
    f = (-wz * wz * r[0], v * wz - wz * wz * r[1], G)
    pitches = {}
    for lever in ((0.0, 0.0, 0.0), r):
        att = Attitude(tau=4.0, lever=lever)
        t = 0.0
        while t < 20.0:
            if round(t * 100) % 2 == 0:
                att.add_speed(t, v)
            att.add_imu(t, f, (0.0, 0.0, wz))
            t += 0.01
        pitches[lever] = (att.roll, att.pitch)
    assert abs(pitches[r][0]) < math.radians(0.05) and abs(pitches[r][1]) < math.radians(0.05)
    assert abs(pitches[(0.0, 0.0, 0.0)][1]) > math.radians(0.5)  # the error it takes out is there


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


def test_a_start_in_free_fall_waits_for_a_sample_of_one_g():
    # the simulator's spawn: the first sample after the drop reads 0.2 g with the x of a 4 deg slope
    a = Attitude(start_band=0.1)
    a.add_imu(0.00, (0.68, 0.0, 2.15), (0.0, 0.0, 0.0))
    assert not a.started
    a.add_imu(0.01, (0.68, 0.0, 9.78), (0.0, 0.0, 0.0))
    assert a.started and abs(math.degrees(a.pitch) + 4.0) < 0.1
    b = Attitude()  # any first sample (the roscpp guard's copy)
    b.add_imu(0.00, (0.68, 0.0, 2.15), (0.0, 0.0, 0.0))
    assert b.started and math.degrees(b.pitch) < -15.0
