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
