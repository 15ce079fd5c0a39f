"""Tilt from the accelerometer: only samples that look like gravity set it, and the first
ones are averaged rather than one of them believed for a time constant."""
import math
from types import SimpleNamespace

import numpy as np
import pytest

from quadrivio_localization.leveling import G, Leveller

ROLL, PITCH = math.radians(4.0), math.radians(-7.0)
TAU = 1.0


def vehicle():
    mount = SimpleNamespace(rpy=(0.0, 0.0, 0.0))
    return SimpleNamespace(sensors={"imu_link": mount, "mag_link": mount})


def gravity(roll: float, pitch: float, scale: float = 1.0):
    """What a still accelerometer at this tilt reads."""
    return (-G * scale * math.sin(pitch), G * scale * math.sin(roll) * math.cos(pitch),
            G * scale * math.cos(roll) * math.cos(pitch))


def test_a_start_up_ramp_does_not_set_the_tilt():
    """A driver whose filter starts from zeros (and a vehicle settling on its suspension):
    the first reading says nothing of gravity; one sample of it used to hold the tilt 70
    degrees off for a second, and the magnetometer's heading with it."""
    lev = Leveller(vehicle(), TAU)
    rng = np.random.default_rng(4)
    ramp = [0.0, 0.02, 0.2, 0.6, 0.75, 0.85, 0.95, 1.1, 1.05]
    t = 0.0
    for k in range(40):
        t = 0.01 * k
        scale = ramp[k] if k < len(ramp) else 1.0
        f = np.array(gravity(ROLL, PITCH, scale)) + rng.normal(0.0, 0.05, 3)
        lev.add_imu(t, tuple(f) if k else (-0.26, 0.02, -0.11), (0.0, 0.0, 0.0))
    assert lev.rejected >= 4
    # after 0.4 s (less than half the time constant): the mean of the good samples
    assert lev.roll == pytest.approx(ROLL, abs=math.radians(0.5))
    assert lev.pitch == pytest.approx(PITCH, abs=math.radians(0.5))


def test_shocks_leave_the_tilt_alone():
    lev = Leveller(vehicle(), TAU)
    for k in range(300):
        lev.add_imu(0.01 * k, gravity(ROLL, PITCH), (0.0, 0.0, 0.0))
    for k in range(300, 320):  # a pothole: 2 g up, then nearly free fall, sideways
        f = (5.0, -8.0, 2.0 * G) if k % 2 else (3.0, 4.0, 0.5)
        lev.add_imu(0.01 * k, f, (0.0, 0.0, 0.0))
    assert lev.rejected == 20
    assert lev.roll == pytest.approx(ROLL, abs=1e-9) and lev.pitch == pytest.approx(PITCH, abs=1e-9)


def test_after_the_start_it_is_a_low_pass():
    lev = Leveller(vehicle(), TAU)
    for k in range(200):
        lev.add_imu(0.01 * k, gravity(0.0, 0.0), (0.0, 0.0, 0.0))
    for k in range(200, 300):  # a 1 s step to the new tilt
        lev.add_imu(0.01 * k, gravity(ROLL, 0.0), (0.0, 0.0, 0.0))
    assert lev.roll == pytest.approx(ROLL * (1.0 - math.exp(-1.0)), rel=0.02)


def test_no_gravity_yet_means_level():
    lev = Leveller(vehicle(), TAU)
    lev.add_imu(0.0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.1))
    assert lev.t is None and lev.roll == 0.0 and lev.pitch == 0.0
    assert lev.level_mag((20.0, 5.0, -40.0)) == pytest.approx((20.0, 5.0))


def test_a_late_imu_is_levelled_with_the_speed_of_its_own_time():
    """Level ground, the vehicle speeding up and braking (2 m/s^2) in a turn; the wheel
    speeds arrive when measured, the IMU 0.15 s after (a driver's filter, a USB buffer).
    Levelled with the speed of when it arrived, each sample's forward and centripetal
    terms were 0.15 s off its own: a pitch and roll of a degree or more, from nothing."""
    lev = Leveller(vehicle(), TAU)
    yaw_rate = 0.3

    def v(t):
        return 2.0 + math.sin(2.0 * t)

    def a(t):
        return 2.0 * math.cos(2.0 * t)

    events = [(k / 50.0, "speed", k / 50.0) for k in range(1000)]
    events += [(k / 100.0 + 0.15, "imu", k / 100.0) for k in range(2000)]
    worst = 0.0
    for _, kind, t in sorted(events, key=lambda e: (e[0], e[1] == "imu")):
        if kind == "speed":
            lev.add_speed(t, v(t))
            continue
        f = (a(t), v(t) * yaw_rate, G)  # level: forward acceleration, centripetal, gravity
        rate = lev.add_imu(t, f, (0.0, 0.0, yaw_rate))
        assert rate == pytest.approx(yaw_rate, rel=1e-3)
        if t > 3.0:
            worst = max(worst, abs(lev.roll), abs(lev.pitch))
    assert math.degrees(worst) < 0.2


def test_speeds_out_of_order_or_repeated_are_ignored():
    lev = Leveller(vehicle(), TAU)
    lev.add_speed(1.0, 2.0)
    lev.add_speed(1.1, 2.2)
    lev.add_speed(1.05, 9.0)  # older than the newest
    lev.add_speed(1.1, 9.0)  # the same time again
    assert lev.speed_and_accel() == pytest.approx((2.2, 2.0))
    assert lev.speed_and_accel(1.02) == pytest.approx((2.0, 2.0))
    assert lev.speed_and_accel(0.5) == pytest.approx((2.0, 2.0))  # before the history: its oldest


def _drive_then_silence(lev, speed_period, t_silent, t_end, accel=2.2):
    """Standing for 1 s, then speeding up at ``accel`` on level ground, with the wheel speed
    every ``speed_period`` s until ``t_silent``; then the wheel speed stops (a frozen PLC
    client) and the vehicle brakes to a stop at 3 m/s^2 and stands. Returns the worst tilt
    [deg] in each second."""
    worst, v, next_speed = {}, 0.0, 0.0
    for k in range(int(t_end / 0.01)):
        t = 0.01 * k
        a = (accel if t >= 1.0 else 0.0) if t < t_silent else (-3.0 if v > 0.0 else 0.0)
        if t >= next_speed - 1e-9 and t < t_silent:
            lev.add_speed(t, v)
            next_speed += speed_period
        lev.add_imu(t, (a, 0.0, G), (0.0, 0.0, 0.0))
        v = max(0.0, v + a * 0.01)
        worst[int(t)] = max(worst.get(int(t), 0.0), math.degrees(max(abs(lev.roll), abs(lev.pitch))))
    return worst


def test_a_silent_wheel_speed_leaves_no_acceleration_behind():
    """The wheel speed stops while the vehicle speeds up (faults_fast's frozen client):
    its last slope must not stay in. It did: the vehicle stood braked for 9.6 s with the
    pitch at 12.5 deg, and the magnetometer levelled with it turned the heading 0.5 rad.
    (While it brakes unseen the tilt is wrong, and cannot be otherwise.)"""
    lev = Leveller(vehicle(), TAU, stale_after=0.25)
    worst = _drive_then_silence(lev, 0.05, 3.0, 12.0)
    assert worst[2] < 0.3  # while the speed comes: no tilt from the acceleration
    assert max(worst[s] for s in range(9, 12)) < 0.3  # standing, no speed: the tilt is gravity's again
    assert lev.speed_and_accel(11.0)[1] == 0.0
    assert lev.speed_and_accel(3.1)[1] == pytest.approx(2.2, rel=0.01)  # within stale_after of the newest


def test_a_slow_wheel_speed_stream_keeps_its_acceleration_between_messages():
    """Our PLC sends 20 states a second; a stream of 2 keeps its slope for three of its own
    intervals, and still loses it once silent."""
    lev = Leveller(vehicle(), TAU, stale_after=0.25)
    worst = _drive_then_silence(lev, 0.5, 3.0, 12.0)
    assert lev.speed_and_accel(4.0)[1] == pytest.approx(2.2, rel=0.01)
    assert lev.speed_and_accel(4.1)[1] == 0.0
    assert max(worst[s] for s in range(9, 12)) < 0.3
