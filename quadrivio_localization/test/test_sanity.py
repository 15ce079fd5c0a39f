"""Readings checked for physical sense: a unit declared wrong is named, not run on."""
import pytest

from quadrivio_localization import sanity


@pytest.mark.parametrize("field, level, needle", [
    (45e-6, "", ""), (30e-6, "", ""), (60e-6, "", ""),
    # the recording: an Xsens field normalised to ~0.9, declared three ways
    (0.89e-4, "warn", "normalised to the local Earth field"),  # as gauss: 89 uT
    (0.9e-6, "error", "normalised to the local Earth field"),  # as microtesla: 0.9 uT
    (0.9, "error", "normalised to the local Earth field"),  # as tesla: 0.9 T (GTSAM's traceback before)
    (45.0, "error", "tesla declared for microtesla data"),
    (4.5e-3, "error", "gauss declared for microtesla data"),
    (45e-3, "error", "microtesla declared for nanotesla data"),
    (8e-6, "warn", "a unit or scale mistake"),
    (200e-6, "warn", ""),
])
def test_field_strengths(field, level, needle):
    got, text = sanity.check_field([field] * 10 + [field * 1.05] * 5)
    assert got == level, text
    if level:
        assert "where the Earth's is 22-67 uT" in text
        assert needle in text, text


@pytest.mark.parametrize("force, level, needle", [
    (9.81, "", ""), (10.4, "", ""),
    (1.0, "error", "in g: set the mapping's imu accel_scale to 9.80665"),
    (981.0, "error", "cm/s^2"),
    (7.0, "warn", "unit or scale"),
])
def test_gravity(force, level, needle):
    got, text = sanity.check_gravity([force] * 20)
    assert got == level, text
    assert needle in text


def test_check_all_and_the_first_error():
    results = sanity.check_all([0.9] * 5, [9.81] * 5)
    assert len(results) == 1 and sanity.first_error(results).startswith("the magnetometer reads a field of 9e+05 uT")
    assert sanity.check_all([], []) == [] and sanity.first_error([]) is None


def _drive(scale, radius=0.3175, seed=0):
    """A vehicle driving a 20 m circle at 1.5-3 m/s for 60 s: wheel speeds at 50 Hz times
    ``scale`` (a unit mistake), fixes at 5 Hz with 0.3 m of noise, about Milan."""
    import math

    import numpy as np

    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 60.0, 0.02)
    v = 2.25 + 0.75 * np.sin(t / 7.0)
    s = np.cumsum(v) * 0.02
    x, y = 20.0 * np.cos(s / 20.0), 20.0 * np.sin(s / 20.0)
    wheel = [(float(a), float(b * scale * (1.0 + 0.02 * rng.standard_normal()))) for a, b in zip(t, v)]
    fixes = [(float(t[k]), 45.478 + (y[k] + 0.3 * rng.standard_normal()) / 111_132.0,
              9.2277 + (x[k] + 0.3 * rng.standard_normal()) / (111_320.0 * math.cos(math.radians(45.478))))
             for k in range(0, len(t), 10)]
    return wheel, fixes


@pytest.mark.parametrize("scale, needle", [(1.0, None), (1.05, None), (3.6, "km/h taken for m/s"),
                                           (1 / 3.6, "applied to data already in m/s"), (2.23694, "mph taken for m/s"),
                                           (-1.0, "reversed sign"), (1 / 0.3175, "angular speed"),
                                           (0.4, "a unit, scale or sign mistake")])
def test_the_wheel_speed_against_the_gps_speed(scale, needle):
    from quadrivio_localization.sanity import check_speed

    wheel, fixes = _drive(scale)
    level, text = check_speed(wheel, fixes, 0.3175)
    if needle is None:
        assert level == "" and text == ""
    else:
        assert level == "warn" and needle in text, text


def test_too_little_motion_is_not_judged():
    from quadrivio_localization.sanity import check_speed

    wheel, fixes = _drive(3.6)
    standing = [(t, 0.0) for t, _ in wheel]
    still = [(t, fixes[0][1], fixes[0][2]) for t, _, _ in fixes]
    assert check_speed(standing, still) == ("", "")
    assert check_speed(wheel[:200], fixes[:20]) == ("", "")  # 4 s: too few spans
