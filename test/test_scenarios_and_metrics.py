"""Scenario files validate against the nodes' parameters; metrics from synthetic runs."""
import math

import numpy as np
import pytest

from quadrivio.metrics import CONTRACT_KEYS, RunData, Series, compute
from quadrivio.scenario import load_scenario, scenarios_dir
from quadrivio_config import ConfigError


@pytest.mark.parametrize("name", ["figure_eight", "rough_terrain", "orchard", "field"])
def test_shipped_scenarios_load(name):
    s = load_scenario(name)
    assert s.name == name and s.run.end == "path_done"


def test_planned_scenarios_check_their_map_and_goal(tmp_path):
    from quadrivio.scenario import map_file

    assert map_file(load_scenario("orchard")).endswith("scenarios/maps/orchard.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nmap: {file: nowhere.yaml}\n")
    with pytest.raises(ConfigError, match="nowhere.yaml: file not found"):
        load_scenario(str(bad))
    bad.write_text(f"name: bad\nmap: {{file: {scenarios_dir()}/maps/orchard.yaml}}\n"
                   "path: {kind: goal, goal: [500.0, 0.0, 0.0]}\n")
    with pytest.raises(ConfigError, match="outside the map"):
        load_scenario(str(bad))
    bad.write_text("name: bad\npath: {kind: goal, goal: [5.0, 0.0, 0.0]}\n")
    with pytest.raises(ConfigError, match="needs a map"):
        load_scenario(str(bad))


def test_planned_metrics():
    """Goal errors from the last true pose, collisions as entries into occupied cells, and
    none of them for a run without a planner."""
    from quadrivio.metrics import PLANNED_KEYS
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.maps import OccupancyGrid

    t = np.arange(0.0, 20.0, 0.1)
    x = t.copy()  # 1 m/s along y = 0
    gt = Series(t, {"x": x, "y": np.zeros_like(t), "yaw": np.zeros_like(t), "vx": np.ones_like(t),
                    "wz": np.zeros_like(t)})
    data = np.zeros((40, 150), np.int8)
    data[22:24, 50:52] = 100  # a post the vehicle's side brushes past at x = 10 (y from 0.2 to 0.4)
    data[:, 120:122] = 100  # a wall across at x = 24: never reached
    grid = OccupancyGrid(data, 0.2, (0.0, -4.2, 0.0))
    fp = Footprint.from_vehicle(load_vehicle())
    planner = Series(np.array([0.5, 1.0]), {"state": np.array([1.0, 2.0]), "planning_time": np.array([0.0, 0.42]),
                                            "length": np.array([0.0, 19.9])})
    poses = np.column_stack([np.linspace(0, 19.9, 200), np.zeros(200), np.zeros(200)])
    run = RunData(ground_truth=gt, estimate=gt, predicted=gt, gps=Series.empty(), path=poses[:, :2],
                  status=Series.empty(), goal=(20.0, 0.3, math.radians(10)), map=grid, planner=planner,
                  path_poses=poses, footprint=fp)
    m = compute(run)
    assert m["goal_position_error_m"] == pytest.approx(math.hypot(20.0 - 19.9, 0.3))
    assert m["goal_heading_error_deg"] == pytest.approx(10.0)
    assert m["collisions"] == 1
    assert m["path_length_m"] == pytest.approx(19.9)
    assert m["plan_time_s"] == pytest.approx(0.42)
    reference = RunData(ground_truth=gt, estimate=gt, predicted=gt, gps=Series.empty(), path=poses[:, :2],
                        status=Series.empty(), planner=Series(np.array([0.5]), {"state": np.array([0.0]),
                                                                                "planning_time": np.array([0.0]),
                                                                                "length": np.array([0.0])}),
                        path_poses=poses)
    assert all(compute(reference)[k] is None for k in PLANNED_KEYS)


def test_an_actor_standing_where_the_vehicle_starts_is_refused(tmp_path):
    """A person 0.5 m ahead of the spawn overlaps the vehicle's body at t = 0: refused with
    the actor's name. Beside it, or a box that only comes near, loads."""
    bad = tmp_path / "bad.yaml"
    for actor, refused in (("{name: p, kind: person, waypoints: [[0.5, 0.0]]}", True),
                           ("{name: p, kind: person, waypoints: [[2.8, 0.0], [9.0, 0.0]]}", True),  # on its front (2.665)
                           ("{name: p, kind: person, waypoints: [[3.0, 0.0], [9.0, 0.0]]}", False),  # 0.035 m ahead
                           ("{name: p, kind: person, waypoints: [[0.5, 1.2]]}", False),
                           ("{name: v, kind: vehicle, waypoints: [[0.0, 2.0]], yaw: 0.0}", False),
                           ("{name: v, kind: vehicle, waypoints: [[0.0, 1.5]], yaw: 1.5708}", True),
                           ("{name: barn, kind: object, size: [20, 20, 3], waypoints: [[0.0, 0.0]]}", True)):
        bad.write_text(f"name: bad\nsim: {{spawn: {{x: 1.0, y: 0.0, yaw: 0.0}}}}\nactors: [{actor}]\n")
        if refused:
            with pytest.raises(ConfigError, match="actor '.*' stands where the vehicle starts"):
                load_scenario(str(bad))
        else:
            assert load_scenario(str(bad)).name == "bad"
    for name in ("person_on_path", "orchard_blocked", "orchard_crossing", "dog_runs_out"):
        load_scenario(name)  # the shipped ones load


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


def test_the_followers_own_cross_track_needs_no_ground_truth():
    """xte_est_*: the cross-track error the follower reported while FOLLOWING (of the estimated
    pose, signed left positive): all a recording of the real vehicle says about tracking."""
    run = circle_run(with_truth=False)
    assert compute(run)["xte_est_rmse_m"] is None  # statuses without a cross-track: nothing to say
    t = np.arange(0.0, 10.0, 0.02)
    status = np.where(t < 1.0, 0, np.where(t < 9.0, 1, 2))  # WAITING, FOLLOWING, DONE
    xt = np.where(np.arange(len(t)) % 2 == 0, 0.3, -0.4)  # alternating sides: |.| counts
    xt[t < 1.0] = 5.0  # not yet following (the start 5 m off the path): not counted
    xt[t >= 9.0] = 7.0  # done, parked off the path: not counted
    xt[(t >= 4.0) & (t < 4.1)] = math.nan  # a status without a number: skipped, not a NaN metric
    run.status = Series(t, {"status": status, "progress": np.zeros_like(t), "cross_track": xt})
    m = compute(run)
    assert m["xte_rmse_m"] is None  # the true one still needs the truth
    assert m["xte_est_max_m"] == pytest.approx(0.4)
    assert m["xte_est_rmse_m"] == pytest.approx(math.sqrt((0.3 ** 2 + 0.4 ** 2) / 2), rel=0.01)
    assert compute(circle_run())["xte_est_max_m"] is None  # a follower without cross-track in its status


def test_a_scenario_must_end_on_duration_covering_the_program(tmp_path):
    from quadrivio_navigation.excitation import ExcitationParams, build

    s = load_scenario("excitation")
    assert s.run.end == "duration" and s.run.max_duration >= build(ExcitationParams()).duration + 1.0
    for text, message in (("name: short\nexcitation: {speed_hold: 10.0}\nrun: {end: duration, max_duration: 60.0}\n",
                           "max_duration >= "),
                          ("name: wrong\nexcitation: {handlebar_steps: [0.9]}\nrun: {end: duration, max_duration: 600}\n",
                           "beyond max_handlebar")):
        (tmp_path / "bad.yaml").write_text(text)
        with pytest.raises(ConfigError, match=message):
            load_scenario(str(tmp_path / "bad.yaml"))


def test_a_scenario_chooses_the_vehicle(tmp_path):
    """vehicle: overrides vehicle.yaml's keys (drive train, masses, limits) for the whole run,
    validated like every other section; the rest of the vehicle stays."""
    from quadrivio.scenario import vehicle
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle

    f = tmp_path / "heavy_4wd.yaml"
    f.write_text("name: heavy_4wd\nvehicle: {drivetrain: {drive: 4wd_locked}, body: {mass: 450.0}, "
                 "steering: {max_angle: 0.35}}\n")
    s = load_scenario(str(f))
    v, default = vehicle(s), load_vehicle()
    assert v.drivetrain.drive == "4wd_locked" and default.drivetrain.drive == "2wd"
    assert v.body.mass == 450.0 and v.steering.max_angle == 0.35
    assert v.wheelbase == default.wheelbase and v.wheels == default.wheels
    assert 'value="450' not in build_urdf(default) and build_urdf(v) != build_urdf(default)
    plain = tmp_path / "plain.yaml"
    plain.write_text("name: plain\n")
    assert vehicle(load_scenario(str(plain))) == default


@pytest.mark.parametrize("section,message", [
    ("{drivetrain: {drive: 3wd}}", r"vehicle.*drive.*3wd"),
    ("{body: {mass: -5}}", r"vehicle.*mass.*-5"),
    ("{wheelbase: 1.2, tyres: {}}", r"vehicle.*tyres"),
    ("4wd", r"vehicle"),
])
def test_bad_vehicle_overrides_name_the_problem(tmp_path, section, message):
    f = tmp_path / "bad.yaml"
    f.write_text(f"name: bad\nvehicle: {section}\n")
    with pytest.raises(ConfigError, match=message):
        load_scenario(str(f))


def test_gps_fix_fraction_is_time_with_a_fix_not_messages():
    """The issue's recording: fixes at 1 Hz, then 14 s and 27 s with no message at all. Counted
    by messages every one was a fix (1.0); by time, 41 s of 100 had none."""
    from quadrivio.metrics import fix_time

    t = np.concatenate([np.arange(0.0, 30.0), np.arange(44.0, 60.0), np.arange(87.0, 101.0)])
    frac, gap = fix_time(t, np.zeros(len(t)), (0.0, 100.0))
    assert gap == pytest.approx(28.0)  # the fixes of 59 s and 87 s
    assert frac == pytest.approx(1.0 - (15.0 - 1.5 + 28.0 - 1.5) / 100.0, abs=1e-9)  # beyond 1.5 periods
    # a receiver that says "no fix" for the same time is the same
    status = np.zeros(101)
    status[30:44] = -1
    status[60:87] = -1
    frac2, gap2 = fix_time(np.arange(0.0, 101.0), status, (0.0, 100.0))
    assert frac2 == pytest.approx(frac, abs=1e-9) and gap2 == pytest.approx(gap)
    assert fix_time(t, -np.ones(len(t)), (0.0, 100.0)) == (0.0, 100.0)


def test_speed_is_read_against_its_limit():
    """stack_efficiency: the achieved factor over cores / CPU s per simulated s, the share of
    the machine the run kept busy (issue 28)."""
    from quadrivio.metrics import cpu_metrics

    m = cpu_metrics(cpu_s=60.0, sim_s=100.0, wall_s=40.0, cores=2)  # factor 2.5 at 0.6 CPU s per sim s
    assert m["stack_cpu_s_per_sim_s"] == pytest.approx(0.6)
    assert m["stack_efficiency"] == pytest.approx(2.5 / (2 / 0.6))  # 0.75 of the two cores
    assert cpu_metrics(None, 100.0, 40.0, 2) == {"stack_cpu_s_per_sim_s": None, "stack_efficiency": None}
    assert cpu_metrics(60.0, 100.0, None, 2)["stack_efficiency"] is None


def test_a_replanned_route_counts_each_path_up_to_where_the_next_took_over():
    """A replan starts where the vehicle is on the old path: the route is the old path up to
    there and the new one whole, not the replan's length alone (a U-turn that replanned 12 m
    before the goal was reported as a 12 m route)."""
    from quadrivio.metrics import route_length

    first = np.column_stack([np.linspace(0.0, 30.0, 301), np.zeros(301)])  # 30 m along y = 0
    # replanned at x = 18.05 (between samples), around something: up 2 m, along, back down to x = 30
    second = np.array([[18.05, 0.0], [20.0, 2.0], [28.0, 2.0], [30.0, 0.0]])
    leg = math.hypot(1.95, 2.0) + 8.0 + math.hypot(2.0, 2.0)
    assert route_length([first, second]) == pytest.approx(18.05 + leg)
    # a third, from the second's middle; the path passing its own start again does not confuse it
    third = np.array([[24.0, 2.0], [24.0, 6.0]])
    assert route_length([first, second, third]) == pytest.approx(18.05 + math.hypot(1.95, 2.0) + 4.0 + 4.0)
    assert route_length([first]) == pytest.approx(30.0)
    assert route_length([first, np.zeros((0, 2))]) == pytest.approx(30.0)  # an empty path: no route after it


def test_the_cross_track_error_of_a_replanned_run_is_against_the_path_in_force_in_metrics_and_plot(monkeypatch):
    """A run that drove 20 m east, then was replanned onto a route 40 m north of where it
    started: the error of each time is to the path it followed then, in the metrics and in
    errors.png alike (the plot measured every time against the last path: 40 m at the start
    of a run that never left its path by more than 0.1 m)."""
    from quadrivio import plots
    from quadrivio.metrics import RunData, Series, cross_track_in_force

    t = np.arange(0.0, 40.0, 0.1)
    first = t < 20.0
    x = np.where(first, t, 20.0)
    y = np.where(first, 0.1, 0.1 + (t - 20.0) * 2.0)  # then north along x = 20
    yaw = np.where(first, 0.0, math.pi / 2)
    gt = Series(t, {"x": x, "y": y, "yaw": yaw, "vx": np.ones(len(t)), "wz": np.zeros(len(t))})
    old = np.column_stack([np.linspace(0.0, 40.0, 81), np.zeros(81)])
    new = np.column_stack([np.full(81, 20.0), np.linspace(0.0, 80.0, 81)])
    run = RunData(ground_truth=gt, estimate=gt, predicted=Series.empty(), gps=Series.empty(), path=new,
                  status=Series.from_rows([(0.0, 1, 0.0, 0.0), (39.9, 2, 1.0, 0.0)], ("status", "progress",
                                                                                       "cross_track")),
                  paths=[(0.0, old), (20.0, new)])
    xt = cross_track_in_force(run, 0.0, 40.0)
    assert np.max(xt[:, 1]) == pytest.approx(0.1, abs=1e-9) and len(xt) == len(t)
    single = RunData(**{**run.__dict__, "paths": [(0.0, new)]})  # one path: measured against it
    assert np.max(cross_track_in_force(single, 0.0, 40.0)[:, 1]) == pytest.approx(20.0, abs=1e-6)

    drawn = {}
    monkeypatch.setattr(plots, "_save", lambda fig, path: drawn.setdefault("fig", fig))
    plots.errors(run, "unused.png", "replanned")
    line = next(ln for ln in drawn["fig"].axes[2].lines if ln.get_label() == "true pose")
    assert np.max(line.get_ydata()) == pytest.approx(0.1, abs=1e-9)


def _collisions_by_every_pose(gt, grid, fp, lethal=65):
    """collision_events' definition, every ground-truth pose tested cell by cell: the
    events, and whether each pose touched."""
    from quadrivio_navigation.costmap import footprint_cells

    occupied = grid.data >= lethal
    h, w = occupied.shape
    events, inside, hits = 0, False, []
    for x, y, yaw in zip(gt["x"], gt["y"], gt["yaw"]):
        gx, gy, gth = grid.to_grid_frame(float(x), float(y), float(yaw))
        rows, cols = footprint_cells(fp, gx, gy, gth, grid.resolution)
        keep = (rows >= 0) & (cols >= 0) & (rows < h) & (cols < w)
        hit = bool(occupied[rows[keep], cols[keep]].any())
        events += hit and not inside
        inside = hit
        hits.append(hit)
    return events, np.array(hits)


def _cross_track_point_by_point(gt, path):
    a, ab = path[:-1], np.diff(path, axis=0)
    denom = np.maximum((ab ** 2).sum(1), 1e-12)
    out = []
    for x, y in zip(gt["x"], gt["y"]):
        u = np.clip(((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1]) / denom, 0.0, 1.0)
        out.append(math.sqrt(np.min((a[:, 0] + u * ab[:, 0] - x) ** 2 + (a[:, 1] + u * ab[:, 1] - y) ** 2)))
    return np.array(out)


@pytest.mark.parametrize("seed", range(6))
def test_collisions_and_cross_track_match_the_pose_by_pose_definitions(seed):
    """collision_events skips the poses the distance transform puts out of reach of every
    occupied cell, and cross_track takes the points in blocks: both give exactly what testing
    every pose gives, pose by pose, on random maps (rotated origins, some poses off the map,
    posts the footprint grazes and walls it crosses)."""
    from quadrivio.metrics import collision_events, cross_track, touching
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.maps import OccupancyGrid

    rng = np.random.default_rng(seed)
    res = float(rng.choice([0.05, 0.2, 0.5]))
    n = int(40 / res)
    data = np.zeros((n, n), np.int8)
    for _ in range(int(rng.integers(3, 30))):  # posts of a cell or a few
        r, c = rng.integers(0, n, 2)
        k = int(rng.integers(1, 4))
        data[r:r + k, c:c + k] = 100
    if seed % 2:
        data[:, n // 2] = 100  # a wall across the middle
    data[rng.random((n, n)) < 0.001] = 70  # lethal, not 100
    origin = (float(rng.uniform(-25, -15)), float(rng.uniform(-25, -15)), float(rng.uniform(-0.5, 0.5)))
    grid = OccupancyGrid(data, res, origin)
    t = np.arange(0.0, 60.0, 0.05)
    x = 24.0 * np.sin(t / 9.0) + rng.normal(0, 0.05, len(t))  # a wander across the map and off it
    y = 22.0 * np.sin(t / 5.0 + seed)
    yaw = np.unwrap(np.arctan2(np.gradient(y), np.gradient(x)))
    gt = Series(t, {"x": x, "y": y, "yaw": yaw, "vx": np.ones_like(t), "wz": np.zeros_like(t)})
    fp = Footprint(front=float(rng.uniform(1.5, 2.5)), rear=0.4, left=0.6, right=float(rng.uniform(0.5, 0.8)))
    expected, hits = _collisions_by_every_pose(gt, grid, fp)
    assert collision_events(gt, grid, fp) == expected
    assert np.array_equal(touching(gt, grid, fp), hits)
    assert hits.any() and not hits.all()
    assert expected > 0 or seed % 2 == 0  # the wall is entered
    empty = OccupancyGrid(np.zeros((n, n), np.int8), res, origin)
    assert collision_events(gt, empty, fp) == 0
    path = np.column_stack([np.linspace(-20, 20, 333), 5.0 * np.sin(np.linspace(0, 6, 333))])
    xt = cross_track(gt, path, 10.0, 50.0)
    inside = (t >= 10.0) & (t <= 50.0)
    assert np.array_equal(xt[:, 0], t[inside])
    assert np.array_equal(xt[:, 1], _cross_track_point_by_point(
        Series(t[inside], {"x": x[inside], "y": y[inside]}), path))
