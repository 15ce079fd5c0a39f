"""Scenario files validate against the nodes' parameters; metrics from synthetic runs."""
import math

import numpy as np
import pytest

from quadrivio.metrics import CONTRACT_KEYS, RunData, Series, compute
from quadrivio.scenario import load_scenario, scenarios_dir
from quadrivio_description.config import ConfigError


@pytest.mark.parametrize("name", ["figure_eight", "rough_terrain"])
def test_shipped_scenarios_load(name):
    s = load_scenario(name)
    assert s.name == name and s.run.end == "path_done"


def test_bad_scenarios_name_the_problem(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nfollower: {profile: {speed: -3.0}}\n")
    with pytest.raises(ConfigError, match=r"follower.*speed.*-3"):
        load_scenario(str(bad))
    bad.write_text("name: bad\nsim: {terrain: {kind: lava}}\n")
    with pytest.raises(ConfigError, match="lava"):
        load_scenario(str(bad))
    bad.write_text("name: bad\nweather: rain\n")
    with pytest.raises(ConfigError, match="unknown section.*weather"):
        load_scenario(str(bad))
    with pytest.raises(ConfigError, match="not one of .*figure_eight"):
        load_scenario("no_such_scenario")
    assert scenarios_dir().endswith("scenarios")


def circle_run(with_truth=True, offset=0.1):
    """A vehicle on a circle of radius 9 m at 2 m/s; estimates offset sideways by ``offset``."""
    t = np.arange(0.0, 30.0, 0.02)
    w = 2.0 / 9.0
    yaw = w * t + math.pi / 2
    x, y = 9.0 * np.cos(w * t), 9.0 * np.sin(w * t)
    gt = Series(t, {"x": x, "y": y, "yaw": yaw, "vx": np.full_like(t, 2.0), "wz": np.full_like(t, w)})
    te = t[::2]
    est = Series(te, {"x": (9.0 + offset) * np.cos(w * te), "y": (9.0 + offset) * np.sin(w * te),
                      "yaw": w * te + math.pi / 2 + math.radians(1.0)})
    tg = t[::10]
    gps = Series(tg, {"e": 9.0 * np.cos(w * tg), "n": 9.0 * np.sin(w * tg),
                      "status": np.where(tg < 20.0, 0, -1)})
    ang = np.linspace(0, 2 * math.pi, 2000)
    path = np.column_stack([9.05 * np.cos(ang), 9.05 * np.sin(ang)])
    status = Series(np.array([0.0, 1.0, 29.0]), {"status": np.array([0, 1, 2]), "progress": np.array([0, 0, 1.0])})
    return RunData(gt if with_truth else Series.empty(), est, est, gps, path, status)


def test_metrics_against_known_errors():
    m = compute(circle_run(), "circle", 4, wall_duration=15.0)
    assert set(CONTRACT_KEYS) <= set(m)
    assert m["completed"] is True and m["seed"] == 4
    assert m["loc_rmse_m"] == pytest.approx(0.1, abs=1e-3)
    assert m["loc_max_m"] == pytest.approx(0.1, abs=1e-3)
    assert m["loc_heading_rmse_deg"] == pytest.approx(1.0, abs=1e-3)
    assert m["gps_fix_fraction"] == pytest.approx(2 / 3, abs=0.01)
    assert m["gps_rmse_m"] == pytest.approx(0.0, abs=1e-9)
    assert m["xte_rmse_m"] == pytest.approx(0.05, abs=1e-3)
    assert m["max_lateral_accel_mps2"] == pytest.approx(2.0 * 2.0 / 9.0, rel=1e-6)
    assert m["rtf"] == pytest.approx(m["sim_duration_s"] / 15.0)


def test_metrics_without_ground_truth_are_null():
    m = compute(circle_run(with_truth=False), "real", None)
    for key in ("loc_rmse_m", "loc_p95_m", "loc_max_m", "loc_heading_rmse_deg", "pred_rmse_m", "gps_rmse_m",
                "xte_rmse_m", "xte_max_m", "max_lateral_accel_mps2"):
        assert m[key] is None, key
    assert m["gps_fix_fraction"] == pytest.approx(2 / 3, abs=0.01)
    assert m["completed"] is True
