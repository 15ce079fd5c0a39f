"""Magnetometer hard/soft-iron fit: recovers a known distortion, refuses too little turning."""
import math

import numpy as np
import pytest

from quadrivio_localization import factors as F
from quadrivio_localization.mag_calibration import InsufficientExcitation, MagCalibrationError, coverage_deg, fit

H = (1.1, 24.2)  # [uT] east, north
TRUE = np.array([4.0, -2.5, 1.05, 0.96, 0.03])


def readings(theta, noise, seed=0):
    rng = np.random.default_rng(seed)
    m = np.array([F.mag_predict(t, TRUE, H)[0] for t in theta])
    return m + rng.normal(0.0, noise, m.shape)


def test_recovers_known_distortion():
    theta = np.linspace(0, 4 * math.pi, 800)
    r = fit(readings(theta, 0.3), math.hypot(*H))
    assert r.hard_iron == pytest.approx(TRUE[:2], abs=0.1)
    assert r.soft_iron == pytest.approx(TRUE[2:], abs=0.005)
    assert r.rms == pytest.approx(0.3, rel=0.2)
    assert r.coverage > 355
    # The written sigmas cover the actual error.
    assert np.all(np.abs(np.array(r.hard_iron) - TRUE[:2]) < r.hard_iron_sigma)
    assert np.all(np.abs(np.array(r.soft_iron) - TRUE[2:]) < np.array(r.soft_iron_sigma))
    # The model the smoother uses then explains the readings: headings come back.
    for t in (0.3, 2.0, -2.5):
        assert F.mag_heading(F.mag_predict(t, TRUE, H)[0], (*r.hard_iron, *r.soft_iron), H) == pytest.approx(t, abs=0.01)


def test_too_little_turning_is_refused_with_the_reason():
    theta = np.linspace(0.0, math.radians(200), 500)
    with pytest.raises(InsufficientExcitation, match="cover 20[0-9] degrees"):
        fit(readings(theta, 0.3), math.hypot(*H))


@pytest.mark.parametrize("heading", [0.0, 1.2, -2.8])
def test_no_heading_change_is_named_as_such(heading):
    """The original vehicle's 55 s standing still: "the ellipse fit did not converge" named no
    cause; the readings never moved round their circle."""
    with pytest.raises(InsufficientExcitation, match="no heading change: the readings span [0-9.]+ uT"):
        fit(readings(np.full(500, heading), 0.3, seed=2), math.hypot(*H))


def test_too_few_and_bad_readings():
    with pytest.raises(InsufficientExcitation, match="only 10"):
        fit(readings(np.linspace(0, 6.3, 10), 0.1), 24.0)
    with pytest.raises(MagCalibrationError, match="N x 2"):
        fit(np.zeros((100, 3)), 24.0)
    with pytest.raises(MagCalibrationError, match="must be positive"):
        fit(readings(np.linspace(0, 6.3, 100), 0.1), 0.0)


def test_coverage():
    assert coverage_deg(np.radians([0, 90, 180, 270])) == pytest.approx(270)
    assert coverage_deg(np.radians([350, 10])) == pytest.approx(20)
    assert coverage_deg(np.array([1.0])) == 0.0


def test_simulator_calibration_file_matches_the_simulated_magnetometer():
    """quadrivio_sim/config/mag_calibration.yaml (fitted by calibrate_mag to a simulated
    drive) still describes quadrivio_sim/config/mag.yaml's distortion."""
    from quadrivio_config import from_mapping, load_yaml
    from quadrivio_localization.smoother import MagCalibration
    from quadrivio_sim.adapter_params import MagAdapterParams
    from quadrivio_sim.paths import package_file

    path = package_file("config", "mag_calibration.yaml")
    cal = from_mapping(MagCalibration, load_yaml(path)["priors"]["magnetometer"], path)
    sim = from_mapping(MagAdapterParams, load_yaml(package_file("config", "mag.yaml")), "mag.yaml").noise
    S, o = np.reshape(sim.soft_iron, (3, 3)), np.asarray(sim.hard_iron) * 1e6
    assert np.all(np.abs(np.array(cal.hard_iron) - o[:2]) < 2 * cal.hard_iron_sigma)
    assert np.all(np.abs(np.array(cal.soft_iron) - [S[0, 0], S[1, 1], S[0, 1]]) < 2 * np.array(cal.soft_iron_sigma))
