"""The closed loop in one process (``campaign --closed-loop``, quadrivio.closed_loop) against
the ROS stack in lockstep (``experiment --lockstep``), the same scenario and seed: the same
outcome, and the same figures within what their differences by design allow (docs/campaigns.md:
no transport; planning takes no sim time in one process).

* the figure eight: completed both ways, localization, prediction and cross-track RMSE
  within 10 %;
* the orchard (planned, with the lasers, the local layer and the guard): completed both
  ways, no collision, goal error within 0.1 m of each other and localization RMSE within
  10 %. Its cross-track RMSE is not compared: the lattice's path depends on the start
  estimate to the millimetre, and ROS plans from a later one (the map is ready 0.1-0.4 s
  after the first estimate) while the vehicle waits its planning time in sim time.
"""
import json
import os
import subprocess

import pytest
import yaml

pytestmark = pytest.mark.system


def _ros(scenario, out, seed):
    r = subprocess.run(["rosrun", "quadrivio", "experiment", scenario, "--out", str(out), "--seed", str(seed),
                        "--lockstep", "--rtf", "0", "--wall-timeout", "400"], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode in (0, 1), r.stdout[-3000:] + r.stderr[-3000:]
    return json.loads((out / "metrics.json").read_text())


def _in_process(scenario, out, seed):
    r = subprocess.run(["rosrun", "quadrivio", "campaign", scenario, "--seeds", "1", "--first-seed", str(seed),
                        "--closed-loop", "--workers", "1", "--out", str(out)], capture_output=True, text=True,
                       timeout=600)
    assert r.returncode in (0, 1), r.stdout[-3000:] + r.stderr[-3000:]
    name = yaml.safe_load(open(scenario))["name"]
    return json.loads((out / "runs" / f"{name}_s{seed}" / "metrics.json").read_text())


def _close(a, b, rel):
    return abs(a - b) <= rel * max(abs(a), abs(b))


def test_the_figure_eight_in_one_process_as_in_ros(tmp_path):
    from quadrivio.scenario import resolve

    ros, inp = _ros(resolve("figure_eight"), tmp_path / "ros", 0), _in_process(resolve("figure_eight"),
                                                                              tmp_path / "inp", 0)
    assert ros["completed"] is True and inp["completed"] is True
    assert inp["runner"] == "in_process" and inp["sim_s_per_cpu_s"] > 1.0
    for key in ("loc_rmse_m", "pred_rmse_m", "xte_rmse_m"):
        assert _close(ros[key], inp[key], 0.10), (key, ros[key], inp[key])


def test_the_orchard_in_one_process_as_in_ros(tmp_path):
    from quadrivio.scenario import resolve

    with open(resolve("orchard")) as f:
        data = yaml.safe_load(f)
    data["name"] = "orchard_parity"
    data["map"]["file"] = os.path.join(os.path.dirname(resolve("orchard")), data["map"]["file"])
    # the lattice bounded by expansions, not by its wall-clock budget: both plan alike
    data.setdefault("planner", {}).update({"budget": 120.0, "lattice": {"max_expansions": 30000}})
    scenario = tmp_path / "orchard_parity.yaml"
    scenario.write_text(yaml.safe_dump(data))
    ros, inp = _ros(str(scenario), tmp_path / "ros", 0), _in_process(str(scenario), tmp_path / "inp", 0)
    assert ros["completed"] is True and inp["completed"] is True
    assert ros["collisions"] == inp["collisions"] == 0
    assert abs(ros["goal_position_error_m"] - inp["goal_position_error_m"]) <= 0.1
    assert _close(ros["loc_rmse_m"], inp["loc_rmse_m"], 0.10), (ros["loc_rmse_m"], inp["loc_rmse_m"])
