"""The closed loop in one process (``campaign --closed-loop``, quadrivio.closed_loop) against
the ROS stack in lockstep (``experiment --lockstep``), the same scenario and seed: the same
outcome, and the same figures within what their differences by design allow (docs/campaigns.md:
no transport; planning takes no sim time in one process).

* the figure eight: completed both ways, localization, prediction and cross-track RMSE
  within 10 %;
* the orchard (planned, with the lasers, the local layer and the guard): completed both
  ways, no collision, no replan and no stop, goal error within 0.1 m of each other,
  localization and cross-track RMSE within 10 %; the ROS run's planned-run keys and plots
  (this is also ``experiment``'s planned scenario, end to end). In lockstep a plan takes no
  sim time, as in one process, so the vehicle sets off at the same time both ways; their
  paths still differ by a few decimetres of length, the lattice's path depending on the
  start estimate to the millimetre, which transport changes by design. And ROS lockstep
  runs the orchard twice: the same run, message for message (``compare_runs``), the
  planner's searches and the local layer included.
"""
import json
import os
import subprocess

import pytest
import yaml
from conftest import run_at_once

from quadrivio.metrics import PLANNED_KEYS

pytestmark = [pytest.mark.system, pytest.mark.lockstep]


def _both(scenario, folder, seed, ros_runs=1):
    """The scenario's metrics in ROS lockstep (``experiment --lockstep``, into ``ros``, then
    ``ros2``...) and in one process (``campaign --closed-loop``), all made at once (none
    depends on the machine's speed)."""
    ros, inp = folder / "ros", folder / "inp"
    cmds = [["rosrun", "quadrivio", "experiment", scenario, "--out", str(folder / ("ros" + (str(k + 1) if k else ""))),
             "--seed", str(seed), "--lockstep", "--rtf", "0", "--wall-timeout", "500"] for k in range(ros_runs)]
    cmds.append(["rosrun", "quadrivio", "campaign", scenario, "--seeds", "1", "--first-seed", str(seed),
                 "--closed-loop", "--workers", "1", "--out", str(inp)])
    for rc, stdout, stderr in run_at_once(cmds, timeout=700):
        assert rc in (0, 1), stdout[-3000:] + stderr[-3000:]
    name = yaml.safe_load(open(scenario))["name"]
    return (json.loads((ros / "metrics.json").read_text()),
            json.loads((inp / "runs" / f"{name}_s{seed}" / "metrics.json").read_text()))


def _close(a, b, rel):
    return abs(a - b) <= rel * max(abs(a), abs(b))


def test_the_figure_eight_in_one_process_as_in_ros(tmp_path):
    from quadrivio.scenario import resolve

    ros, inp = _both(resolve("figure_eight"), tmp_path, 0)
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
    data.setdefault("planner", {}).update({"budget": 120.0, "lattice": {"max_expansions": 300000}})
    scenario = tmp_path / "orchard_parity.yaml"
    scenario.write_text(yaml.safe_dump(data))
    ros, inp = _both(str(scenario), tmp_path, 0, ros_runs=2)
    assert ros["completed"] is True and inp["completed"] is True
    assert ros["collisions"] == inp["collisions"] == 0
    assert abs(ros["goal_position_error_m"] - inp["goal_position_error_m"]) <= 0.1
    for key in ("loc_rmse_m", "xte_rmse_m"):
        assert _close(ros[key], inp[key], 0.10), (key, ros[key], inp[key])
    # what `experiment` gives a planned run, ROS side: plan on the orchard map, drive out of the
    # first row, U-turn in the headland, park in the second row facing back, touching no tree
    assert set(PLANNED_KEYS) <= set(ros)
    for m in (ros, inp):
        # the follower stops within 0.5 m of the goal by its own estimate, which is 0.3 m off
        assert m["goal_position_error_m"] < 1.0 and m["goal_heading_error_deg"] < 10.0
        assert 45.0 < m["path_length_m"] < 75.0  # 36 m along the row, the U-turn, 10 m back
        assert m["protective_stops"] == 0 and m["false_stops"] == 0  # nothing unmapped in the orchard
    # one plan, followed to the goal (at 30 000 expansions the lattice's eps-3 path from some starts,
    # 64 m with 7 cusps, had the guard hold the vehicle among the trees)
    assert inp["replans"] == 0 and ros["replans"] == 0
    assert 0.0 < ros["plan_time_s"] < 6.0
    assert (tmp_path / "ros" / "trajectory.png").stat().st_size > 20000
    # the same run twice: every stream the same up to the shorter run's end (experiment stops
    # a run on the wall clock when it sees the follower done)
    r = subprocess.run(["rosrun", "quadrivio", "compare_runs", "--prefix", str(tmp_path / "ros" / "run.bag"),
                        str(tmp_path / "ros2" / "run.bag")], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0 and "the same" in r.stdout, r.stdout + r.stderr
    assert "/planner/path" in _streams(tmp_path / "ros" / "run.bag") and \
        "/local_obstacles" in _streams(tmp_path / "ros" / "run.bag")


def _streams(bag_path):
    import rosbag

    with rosbag.Bag(str(bag_path)) as bag:
        return set(bag.get_type_and_topic_info().topics)
