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
