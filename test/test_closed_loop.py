"""The closed loop in one process (quadrivio.closed_loop): the same seed gives the same run,
array for array; the guard on its path stops the vehicle for a person; what it cannot run
is refused with the reason. (Its parity with the ROS stack: test_closed_loop_parity.py.)"""
import math
import os

import numpy as np
import pytest
import yaml

from quadrivio import closed_loop, metrics
from quadrivio.scenario import load_scenario, resolve
from quadrivio.scenario import vehicle as scenario_vehicle
from quadrivio_config import ConfigError

STREAMS = ("ground_truth", "estimate", "predicted", "setpoint", "vehicle", "status", "guard", "calibration")


def _same(a, b) -> bool:
    return len(a) == len(b) and np.array_equal(a.t, b.t) and \
        all(np.array_equal(a[k], b[k], equal_nan=True) for k in a.cols)


def test_the_same_seed_gives_the_same_run_array_for_array():
    s = load_scenario("figure_eight")
    a, b = closed_loop.run(s, 4, max_duration=12.0), closed_loop.run(s, 4, max_duration=12.0)
    for name in STREAMS:
        assert _same(getattr(a.run, name), getattr(b.run, name)), name
    assert len(a.run.setpoint) > 500 and float(np.max(a.run.vehicle["speed"])) > 1.0  # it drove
    c = closed_loop.run(s, 5, max_duration=12.0)
    assert not _same(a.run.estimate, c.run.estimate)  # another seed, other readings


def _person_stays(folder) -> str:
    with open(resolve("person_on_path")) as f:
        data = yaml.safe_load(f)
    data["actors"][0]["start_time"] = 1000.0  # the person stays
    data["name"] = "person_stays"
    path = folder / "person_stays.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_the_native_guard_drives_the_run_the_python_guard_drives(tmp_path):
    """guard_impl: the roscpp node's core through ctypes (the default, as sim.launch's) and the
    Python reference make the same run, array for array, slowing and holding for a person."""
    s = load_scenario(_person_stays(tmp_path))
    a = closed_loop.run(s, 2, max_duration=22.0)
    b = closed_loop.run(s, 2, max_duration=22.0, guard_impl="guard")
    for name in STREAMS:
        assert _same(getattr(a.run, name), getattr(b.run, name)), name
    assert np.any(a.run.guard["limit"] < 0.1)  # it held the vehicle: the guard's decisions were tested
    with pytest.raises(ValueError, match="guard_impl must be one of guard_cpp, guard"):
        closed_loop.run(s, 2, max_duration=1.0, guard_impl="guard_py")


def test_the_guard_stops_the_vehicle_short_of_a_person(tmp_path):
    s = load_scenario(_person_stays(tmp_path))
    r = closed_loop.run(s, 1, max_duration=25.0)
    m = metrics.compute(r.run, s.name, 1, r.wall_s, scenario_vehicle(s))
    assert m["collisions"] == 0 and m["min_clearance_m"] >= 0.3, m
    assert m["time_blocked_s"] > 5.0  # held in front of the person, not driven around or through
    speed = r.run.ground_truth["vx"][r.run.ground_truth.t > 20.0]
    assert np.all(np.abs(speed) < 0.1)


def _with(folder, name, edit) -> str:
    with open(resolve(name)) as f:
        data = yaml.safe_load(f)
    if data.get("map", {}).get("file"):  # relative to the scenario's folder
        data["map"]["file"] = os.path.join(os.path.dirname(resolve(name)), data["map"]["file"])
    edit(data)
    path = folder / f"{data['name']}.yaml"
    path.write_text(yaml.safe_dump(data))
    return str(path)


def test_the_simulated_drivers_no_echo_reads_back():
    """What the laser adapters publish for each no_return (quadrivio_sim.noise.driver_ranges)
    the guard's and the layer's reading (fields.rep117_ranges) turns back into REP 117."""
    from quadrivio_navigation.fields import rep117_ranges
    from quadrivio_sim.noise import driver_ranges

    rep = [math.inf, 5.0, 0.1, 30.0, -math.inf, math.nan, math.inf]
    assert driver_ranges(rep, 30.0, "zero")[:4] == [0.0, 5.0, 0.1, 30.0]
    assert driver_ranges(rep, 30.0, "beyond_max")[0] == 31.0
    for mode in ("inf", "zero", "beyond_max"):
        assert np.array_equal(rep117_ranges(driver_ranges(rep, 30.0, mode), 30.0, mode), rep, equal_nan=True), mode
    with pytest.raises(ValueError, match="no_return 'nan'"):
        driver_ranges(rep, 30.0, "nan")


def test_lasers_whose_drivers_predate_rep117_make_the_same_run_once_the_guard_is_told(tmp_path):
    """The lasers published as LMS1xx (no echo: 0.0) and pointcloud_to_laserscan without use_inf
    (range_max + 1) publish them. With the guard's scanners' no_return saying so, a lane crossed
    by a person, replanned around the local layer's marks (scenarios/lms1xx_lasers.yaml), is
    orchard_crossing's run array for array (the layer reads the guard's scanners). Without, in the open field of the figure eight the
    guard stops the vehicle from the start, and the run's log says why and what to set."""
    lasers = {"laser_front": {"no_return": "zero"}, "laser_rear": {"no_return": "beyond_max"}}
    told = {"scanners": [{"topic": "scan/front", "frame": "laser_front", "covers": "forward", "no_return": "zero"},
                         {"topic": "scan/rear", "frame": "laser_rear", "covers": "reverse",
                          "no_return": "beyond_max"}]}

    def legacy(data, guard=None):
        data["name"] += "_legacy"
        data.setdefault("sensors", {}).update(lasers)
        if guard:
            data["guard"] = guard
    with open(resolve("orchard_crossing")) as f, open(resolve("lms1xx_lasers")) as g:
        plain, shipped = yaml.safe_load(f), yaml.safe_load(g)
    assert shipped["sensors"] == lasers and shipped["guard"] == told
    for key in ("name", "description", "sensors", "guard"):
        plain.pop(key, None), shipped.pop(key, None)
    assert shipped == plain, "scenarios/lms1xx_lasers.yaml is orchard_crossing but for its lasers"
    a = closed_loop.run(load_scenario("orchard_crossing"), 0, max_duration=13.0)
    b = closed_loop.run(load_scenario("lms1xx_lasers"), 0, max_duration=13.0)
    for name in STREAMS:
        assert _same(getattr(a.run, name), getattr(b.run, name)), name
    pa, pb = a.run.planner, b.run.planner  # (its planning_time is wall time)
    assert np.array_equal(pa.t, pb.t) and np.array_equal(pa["length"], pb["length"], equal_nan=True)
    assert np.array_equal(a.run.local_marks, b.run.local_marks) and len(a.run.local_marks) > 0
    assert len(a.run.planner) >= 2 and np.any(a.run.guard["limit"] < 2.0)  # replanned, slowed: both were tested
    c = closed_loop.run(load_scenario(_with(tmp_path, "figure_eight", legacy)), 0, max_duration=6.0)
    assert np.all(np.abs(c.run.ground_truth["vx"]) < 0.05)
    assert any("guard FAULT: scan/front blinded: 100 % of its rays invalid, 100 % read 0 m" in line and
               line.endswith("no_return: zero") for _, line in c.log), c.log


def test_a_goal_without_a_map_is_refused(tmp_path):
    data = {"name": "goal_no_map", "path": {"kind": "goal", "goal": [10.0, 0.0, 0.0]},
            "sim": {"terrain": {"kind": "flat"}}}
    path = tmp_path / "goal_no_map.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match="needs a map"):
        closed_loop.run(load_scenario(str(path)), 0, max_duration=1.0)


def test_a_run_whose_plan_failed_did_not_complete(tmp_path):
    """The orchard with its goal in a tree: the planner refuses it, the follower never
    reports, and the run did not complete: ``completed`` false in metrics.json and 0 in the
    campaign's table (null there, the campaign's mean left the seed out)."""
    from quadrivio import campaign

    data = yaml.safe_load(open(resolve("orchard")))
    data.update(name="goal_in_tree", path={"kind": "goal", "goal": [21.0, 5.0, 0.0]})
    data["map"]["file"] = os.path.join(os.path.dirname(resolve("orchard")), data["map"]["file"])
    path = tmp_path / "goal_in_tree.yaml"
    path.write_text(yaml.safe_dump(data))
    s = load_scenario(str(path))
    r = closed_loop.run(s, 0, max_duration=10.0)
    assert r.outcome.startswith("planner failed: goal") and "in collision" in r.outcome
    m = closed_loop.write_run(r, s, 0, str(tmp_path / "run"), plots=False)
    assert m["completed"] is False
    fig = campaign._closed_loop_figures(s, 0, m, False)
    assert fig["completed"] == 0.0
    # the campaign's table says which runs did not complete, and how they ended
    done = dict(fig, seed=1, end="completed", outcome="completed", completed=1.0)
    many = [dict(fig, seed=k) for k in range(2, 25)]
    runs = [fig, done] + many
    campaign.write_tables(str(tmp_path), campaign.table(runs, [s.name]), runs, {"mode": "closed loop", "seeds": [0]})
    md = (tmp_path / "campaign.md").read_text()
    assert "Runs that did not complete:" in md and "goal_in_tree seed 1:" not in md
    assert f"- goal_in_tree seed 0: {r.outcome}" in md and "- and 4 more (campaign.json" in md
    # from the recording alone (no outcome) it stays null; a finished run keeps its own
    alone = metrics.compute(r.run, s.name, 0, r.wall_s, scenario_vehicle(s))
    assert alone["completed"] is None
    metrics.settle_completed(alone, "duration", "completed")  # a run that ends on its duration: not judged here
    assert alone["completed"] is None
    done = {"completed": True}
    metrics.settle_completed(done, "path_done", "time limit")
    assert done["completed"] is True


def test_write_run_writes_the_experiment_keys_and_plots(tmp_path):
    s = load_scenario("figure_eight")
    r = closed_loop.run(s, 0, max_duration=8.0)
    m = closed_loop.write_run(r, s, 0, str(tmp_path))
    for key in metrics.CONTRACT_KEYS:
        assert key in m
    assert m["runner"] == "in_process" and m["sim_s_per_cpu_s"] > 0
    assert {"metrics.json", "run_info.json", "log.txt", "trajectory.png"} <= set(os.listdir(tmp_path))
    assert not [f for f in os.listdir(tmp_path) if f.startswith(".")]  # nothing half-written left


@pytest.mark.parametrize("argv, message", [
    (["--ros"], "--ros and --rtf go with --closed-loop"),
    (["--closed-loop", "--rtf", "2"], "--closed-loop --ros"),
    (["--run-plots", "all"], "--run-plots goes with --closed-loop in one process"),
    (["--closed-loop", "--ros", "--run-plots", "none"], "--run-plots goes with --closed-loop in one process"),
])
def test_campaign_refuses_options_that_do_not_go_together(argv, message, capsys):
    from quadrivio import campaign

    with pytest.raises(SystemExit):
        campaign.parse(["figure_eight", "--out", "x"] + argv)
    assert message in capsys.readouterr().err


def test_each_stop_is_kept_with_what_the_guard_saw_and_drawn(tmp_path):
    """The in-process run keeps, for each of the guard's stops, the points it last read from
    each laser (as stop_views draws them): a campaign's notable run shows why it stopped."""
    from quadrivio.obstacle_metrics import obstacle_metrics
    from quadrivio.stop_views import STOP, moving_reach, moving_sources

    s = load_scenario("dog_runs_out")
    r = closed_loop.run(s, 1, max_duration=12.0)
    m = obstacle_metrics(r.run, scenario_vehicle(s))
    assert r.stops == m["protective_stops"] + m["fault_stops"] >= 1
    first = r.stop_scenes[0]
    assert first.action == STOP and first.field_kind == "protective" and first.scanner == "scan/front"
    assert first.nearest is not None and 0.0 <= first.free <= first.protective
    front = first.scans["scan/front"]
    # the nearest point the guard named is one of the front laser's points it read, or, for a
    # stop on where a tracked moving thing may be, a point within its reach of front returns
    off = np.min(np.hypot(front[:, 0] - first.nearest[0], front[:, 1] - first.nearest[1]))
    reach = moving_reach(first)
    if reach is None:
        assert off < 1e-9
    else:
        assert "moving obstacle" in first.reason and 0.0 < off <= reach[0] * reach[1]
        assert len(moving_sources(first)) > 0
    assert 0.0 <= first.scan_ages["scan/front"] <= 0.25
    made = closed_loop.plot_run(r, s, 1, str(tmp_path))
    assert f"stops/stop_01_{first.t:.2f}s.png" in made and (tmp_path / "stops").is_dir()


def test_a_person_crossing_the_lane_is_waited_for_and_a_dog_that_stays_is_driven_round():
    """A way round much longer than the blocked path waits for the path to clear
    (replanning.DetourWait, planner.yaml's detour_wait): in orchard_crossing the person is
    through in seconds and the vehicle goes on along its lane (it drove 94 m round the orchard
    for them); in dog_runs_out the dog stays in the lane, and the way round is taken once the
    path has been blocked detour_wait seconds, from where the vehicle stands."""
    from quadrivio_navigation.replanning import PlannerNodeParams

    wait = PlannerNodeParams().detour_wait
    s = load_scenario("orchard_crossing")
    r = closed_loop.run(s, 0)
    m = metrics.compute(r.run, s.name, 0, r.wall_s, scenario_vehicle(s))
    assert m["completed"] and m["collisions"] == 0 and m["min_clearance_m"] >= 0.3, m
    assert m["path_length_m"] < 62.0, m  # the lane: the first path was 57 m, round the orchard 94
    lines = [line for _, line in r.log if line.startswith("planner:")]
    assert any("waiting up to" in line for line in lines) and any("the path cleared" in line for line in lines), lines
    from quadrivio.plots import blocked_spans  # guard.png's strip

    spans = blocked_spans(r.run.planner, float(r.run.guard.t[-1]))
    assert len(spans) == 1 and 0.0 < spans[0][1] - spans[0][0] < wait, spans

    s = load_scenario("dog_runs_out")
    r = closed_loop.run(s, 0, max_duration=8.0 + wait + 3.0)
    waits = [t for t, line in r.log if "waiting up to" in line]
    rounds = [t for t, line in r.log if line.startswith("planner: replanned of") and waits and t > waits[0]]
    assert waits and rounds, r.log
    first_block = min(t for t, line in r.log if "the path is blocked" in line)
    assert rounds[0] - first_block >= wait - 0.01, (first_block, rounds[0])
    speed = r.run.ground_truth["vx"][(r.run.ground_truth.t > waits[0] + 3.0) & (r.run.ground_truth.t < rounds[0])]
    assert len(speed) and np.all(np.abs(speed) < 0.1)  # it waited standing, short of the dog
