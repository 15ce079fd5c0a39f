"""The obstacle keys of metrics.json on synthetic runs (quadrivio.obstacle_metrics):
clearance by hand, false stops judged by the ground truth, latencies, time blocked."""
import math

import numpy as np
import pytest

from quadrivio.metrics import RunData, Series
from quadrivio.obstacle_metrics import map_points, min_clearance, obstacle_metrics, rectangle_distance
from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint

V = load_vehicle()
FP = Footprint.from_vehicle(V)


def straight_run(t_end=10.0, speed=1.0, stop_at=None):
    t = np.arange(0.0, t_end, 0.02)
    x = speed * np.minimum(t, stop_at if stop_at is not None else t_end)
    gt = Series(t, {"x": x, "y": np.zeros_like(t), "yaw": np.zeros_like(t), "vx": np.full_like(t, speed),
                    "wz": np.zeros_like(t)})
    return gt


def person(x, y, t=(0.0, 100.0)):
    return [(tt, [("bob", "person", "cylinder", x, y, 0.0, 0.6, 0.6)]) for tt in t]


def guard_series(rows):
    a = np.array(rows, dtype=float)
    names = ("action", "limit", "free", "protective", "scan_stamp", "direction", "requested", "zone", "measured",
             "handlebar_requested", "handlebar_measured")
    return Series(a[:, 0], {n: a[:, i + 1] for i, n in enumerate(names)})


def test_rectangle_distance_by_hand():
    pts = np.array([[FP.front + 1.0, 0.0], [0.0, FP.left + 0.5], [FP.front + 3.0, FP.left + 4.0], [0.5, 0.1]])
    d = rectangle_distance(FP, 0.0, 0.0, 0.0, pts)
    assert d == pytest.approx([1.0, 0.5, 5.0, 0.0])
    # rotated a quarter turn: ahead is +y
    d = rectangle_distance(FP, 0.0, 0.0, math.pi / 2, np.array([[0.0, FP.front + 2.0]]))
    assert d == pytest.approx([2.0])


def test_min_clearance_to_a_person_and_map():
    gt = straight_run(t_end=8.0, speed=1.0)  # front edge reaches 8 + front
    bob = person(20.0, 2.0)
    # closest: front-left corner (8 - 0.02 + front, left) to the cylinder (20, 2) r 0.3
    fx = 7.98 + FP.front
    expected = math.hypot(20.0 - fx, 2.0 - FP.left) - 0.3
    assert min_clearance(gt, FP, bob, None) == pytest.approx(expected, abs=0.01)
    assert min_clearance(gt, FP, [], None) is None


def test_the_simulators_own_map_bodies_replace_the_defaults():
    """A run that recorded the bodies its simulator built (/ground_truth/map_bodies: a map with
    other settings than ours, here a tree 2 m wide where the default tree_size would have made
    a box) is judged against them; without them, against the bodies the defaults build."""
    from quadrivio_navigation.maps import OccupancyGrid

    data = np.zeros((60, 60), dtype=np.int8)
    data[20:40, 30:50] = 100  # a 2 m x 2 m blob of 0.1 m cells, (3..5, 2..4) m
    grid = OccupancyGrid(data=data, resolution=0.1, origin=(0.0, 0.0, 0.0))
    gt = Series(np.array([0.0, 1.0]), {"x": np.zeros(2), "y": np.full(2, 3.0), "yaw": np.zeros(2),
                                       "vx": np.zeros(2), "wz": np.zeros(2)})
    # the defaults: boxes over the cells, the nearest face at x = 3 m
    box = min_clearance(gt, FP, [], grid)
    assert box == pytest.approx(3.0 - FP.front, abs=0.06)
    # the simulator's: one cylinder of 1.5 m radius at the blob's centre (4, 3), nearest at x = 2.5 m
    tree = [("map_0", "map", "cylinder", 4.0, 3.0, 0.0, 3.0, 3.0)]
    assert min_clearance(gt, FP, [], grid, bodies=tree) == pytest.approx(2.5 - FP.front, abs=0.06)
    assert min_clearance(gt, FP, [], None, bodies=tree) == pytest.approx(2.5 - FP.front, abs=0.06)


def test_min_clearance_is_the_least_of_every_poses_distance_to_the_bodies_in_reach():
    """min_clearance (a k-d tree's points in reach of each pose) against every point's
    distance, on random bodies and winding tracks, two strides, and tracks that pass out of
    reach of everything."""
    rng = np.random.default_rng(3)
    for case in range(40):
        n_bodies = int(rng.integers(1, 60))
        bodies = [(f"b{k}", "map", str(rng.choice(["cylinder", "box"])), *rng.uniform(-20.0, 20.0, 2),
                   float(rng.uniform(-math.pi, math.pi)), *rng.uniform(0.2, 3.0, 2)) for k in range(n_bodies)]
        t = np.arange(0.0, 30.0, 0.05)
        yaw = np.cumsum(rng.normal(0.0, 0.05, len(t))) + rng.uniform(-math.pi, math.pi)
        speed = rng.uniform(0.5, 3.0)
        x = np.cumsum(speed * 0.05 * np.cos(yaw)) + rng.uniform(-25.0, 25.0)
        y = np.cumsum(speed * 0.05 * np.sin(yaw)) + rng.uniform(-25.0, 25.0)
        gt = Series(t, {"x": x, "y": y, "yaw": yaw, "vx": np.full_like(t, speed), "wz": np.zeros_like(t)})
        stride = int(rng.choice([1, 3]))
        pts = map_points(None, bodies)
        reach = FP.circumscribed_radius + 3.0
        near = []  # every pose's distance to the points within reach of it
        for i in range(0, len(t), stride):
            close = np.hypot(pts[:, 0] - x[i], pts[:, 1] - y[i]) <= reach
            if close.any():
                near.append(float(rectangle_distance(FP, x[i], y[i], yaw[i], pts[close]).min()))
        got = min_clearance(gt, FP, [], None, stride=stride, bodies=bodies)
        if near:
            assert got == pytest.approx(min(near), rel=1e-12, abs=1e-12), case
        else:
            assert got is None, case


def test_protective_stops_judged_by_the_ground_truth():
    gt = straight_run(t_end=10.0, speed=1.0, stop_at=5.0)
    rows = [[0.0, 0, 1.5, 9.0, 1.0, 0.0, 1, 1.0, 0, 1.0, 0, 0], [4.0, 0, 1.5, 3.0, 1.0, 0.0, 1, 1.0, 0, 1.0, 0, 0],
            [5.0, 2, 0.0, 0.8, 1.2, 4.97, 1, 1.0, 0, 1.0, 0, 0], [5.5, 3, 0.0, 0.8, 0.3, 0.0, 1, 1.0, 0, 0.0, 0, 0],
            [7.0, 0, 1.5, 9.0, 0.3, 0.0, 1, 1.0, 0, 0.0, 0, 0]]
    sp_t = np.array([4.9, 5.0, 5.02, 5.04])
    setpoint = Series(sp_t, {"speed": np.array([1.0, 1.0, 0.0, 0.0]), "handlebar": np.zeros(4),
                             "brake": np.array([0.0, 0.0, 1.0, 1.0])})
    vehicle = Series(gt.t, {"speed": gt["vx"], "handlebar": np.zeros(len(gt))})
    # a person 0.8 m ahead of the front edge at the stop: a true stop
    real = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                   vehicle=vehicle, guard=guard_series(rows), actors=person(5.0 + FP.front + 1.1, 0.0), contacts=[])
    m = obstacle_metrics(real, V)
    assert m["protective_stops"] == 1 and m["false_stops"] == 0 and m["collisions"] == 0
    assert m["stop_latencies_ms"] == pytest.approx([50.0])  # the 5.02 s stop setpoint after the 4.97 s scan
    assert m["time_blocked_s"] == pytest.approx(2.0)  # from 5.0 to 7.0
    # nothing anywhere near: a false stop
    empty = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                    vehicle=vehicle, guard=guard_series(rows), actors=person(50.0, 30.0), contacts=[])
    assert obstacle_metrics(empty, V)["false_stops"] == 1
    # the person beside the path (out of the swept field): a false stop too
    beside = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                     vehicle=vehicle, guard=guard_series(rows), actors=person(5.0 + FP.front + 0.5, 2.5), contacts=[])
    assert obstacle_metrics(beside, V)["false_stops"] == 1
    # ...unless they walk into it within the anticipation (a stop for where they will be)
    walking = [(5.0, [("bob", "person", "cylinder", 5.0 + FP.front + 0.5, 2.5, 0.0, 0.6, 0.6)]),
               (6.0, [("bob", "person", "cylinder", 5.0 + FP.front + 0.5, 1.0, 0.0, 0.6, 0.6)])]
    crossing = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                       vehicle=vehicle, guard=guard_series(rows), actors=walking, contacts=[])
    m = obstacle_metrics(crossing, V)
    assert m["false_stops"] == 0 and m["anticipated_stops"] == 1
    assert obstacle_metrics(crossing, V, anticipation=0.3)["false_stops"] == 1
    # ...or cross just beyond the field, where the vehicle driving on at 1 m/s would have met
    # them within the anticipation: 1.0 m beyond the field's end (0.8 m + tolerance 0.5),
    # crossing at 1.25 m/s
    def across(beyond):
        x = 5.0 + FP.front + 0.8 + 0.5 + beyond
        return [(5.0, [("bob", "person", "cylinder", x, 2.5, 0.0, 0.6, 0.6)]),
                (9.0, [("bob", "person", "cylinder", x, -2.5, 0.0, 0.6, 0.6)])]

    ahead = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                    vehicle=vehicle, guard=guard_series(rows), actors=across(1.0), contacts=[])
    m = obstacle_metrics(ahead, V)
    assert m["false_stops"] == 0 and m["anticipated_stops"] == 1
    # 4 m beyond: the vehicle would have driven 2 m in the anticipation's 2 s, short of them
    far = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                  vehicle=vehicle, guard=guard_series(rows), actors=across(4.0), contacts=[])
    assert obstacle_metrics(far, V)["false_stops"] == 1


def test_a_stop_for_a_person_walking_at_the_path_who_stops_short_of_it_is_anticipated_not_false():
    """A person walks straight at the path and stops at its edge to let the vehicle pass:
    by their true future nothing came (a "false" stop before), but by the way they moved
    when the guard stopped they were coming, which no guard can tell from someone who will
    step on: anticipated. Standing there, or walking away from the path, it is false."""
    gt = straight_run(t_end=10.0, speed=1.0, stop_at=5.0)
    rows = [[0.0, 0, 1.5, 9.0, 1.0, 0.0, 1, 1.0, 0, 1.0, 0, 0], [5.0, 2, 0.0, 0.8, 1.2, 4.97, 1, 1.0, 0, 1.0, 0, 0],
            [7.0, 0, 1.5, 9.0, 0.3, 0.0, 1, 1.0, 0, 0.0, 0, 0]]
    x = 5.0 + FP.front + 0.5

    def walk(y_before):  # at y_before 1 s before the stop, at 2.5 m (beside the field) from the stop on
        return [(4.0, [("bob", "person", "cylinder", x, y_before, 0.0, 0.6, 0.6)]),
                (5.0, [("bob", "person", "cylinder", x, 2.5, 0.0, 0.6, 0.6)]),
                (10.0, [("bob", "person", "cylinder", x, 2.5, 0.0, 0.6, 0.6)])]

    def judged(actors):
        run = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(),
                      guard=guard_series(rows), actors=actors, contacts=[])
        m = obstacle_metrics(run, V)
        return m["false_stops"], m["anticipated_stops"]

    assert judged(walk(3.7)) == (0, 1)  # at 1.2 m/s toward the path
    assert judged(walk(1.3)) == (1, 0)  # away from it
    assert judged(walk(2.5)) == (1, 0)  # standing there


def test_a_recording_without_ground_truth_cannot_judge_its_stops():
    """The vehicle's own bag: the stops are counted and drawn at the estimated pose, but
    whether they were false is unknown (null), not 0."""
    from quadrivio.obstacle_metrics import stop_list

    est = straight_run(t_end=10.0, speed=1.0, stop_at=5.0)
    rows = [[0.0, 0, 1.5, 9.0, 1.0, 0.0, 1, 1.0, 0, 1.0, 0, 0], [5.0, 2, 0.0, 0.8, 1.2, 4.97, 1, 1.0, 0, 1.0, 0, 0],
            [7.0, 0, 1.5, 9.0, 0.3, 0.0, 1, 1.0, 0, 0.0, 0, 0]]
    run = RunData(Series.empty(), est, Series.empty(), Series.empty(), None, Series.empty(), guard=guard_series(rows))
    m = obstacle_metrics(run, V)
    assert m["protective_stops"] == 1
    assert m["false_stops"] is None and m["anticipated_stops"] is None
    assert [(t, round(x, 3), y, a) for t, x, y, a in stop_list(run)] == [(5.0, 5.0, 0.0, 2)]
    # no stop at all: nothing to judge, 0 whatever the truth
    calm = RunData(Series.empty(), est, Series.empty(), Series.empty(), None, Series.empty(),
                   guard=guard_series([rows[0], rows[2]]))
    assert obstacle_metrics(calm, V)["false_stops"] == 0


def test_contacts_count_with_body_and_speed():
    gt = straight_run()
    run = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(),
                  contacts=[(3.2, "bob", "person", 1.9), (7.0, "map obstacles (tile 0)", "map", 0.4)])
    m = obstacle_metrics(run, V)
    assert m["collisions"] == 2
    assert m["collision_events"][0] == {"t": 3.2, "body": "bob", "kind": "person", "speed_mps": 1.9}


def test_a_stop_the_vehicle_drove_into_counts_from_its_decision():
    """The guard judged the 4.90 s scan twice without a stop (the obstacle in the warning
    field), then a request's decision at 5.04 s found the vehicle in the protective field:
    no scan showed it there, the latency runs from that decision (10 ms to the brake), not
    140 ms from the scan (dog_runs_out, 2 m/s, seed 1, at factor 1)."""
    gt = straight_run(t_end=10.0, speed=1.0, stop_at=5.0)
    rows = [[4.94, 1, 0.3, 0.68, 0.64, 4.90, 1, 1.5, 0, 0.84, 0, 0], [4.95, 1, 0.3, 0.77, 0.56, 4.90, 1, 1.5, 0, 0.84, 0, 0],
            [5.04, 2, 0.0, 0.67, 0.70, 4.90, 1, 1.5, 0, 0.95, 0, 0], [5.05, 2, 0.0, 1.3, 0.6, 5.00, 1, 1.5, 0, 0.9, 0, 0],
            [5.5, 3, 0.0, 0.6, 0.3, 5.40, 1, 1.5, 0, 0.0, 0, 0]]
    sp_t = np.array([4.95, 5.02, 5.05, 5.06])
    setpoint = Series(sp_t, {"speed": np.array([0.3, 0.3, 0.0, 0.0]), "handlebar": np.zeros(4),
                             "brake": np.array([0.0, 0.0, 1.0, 1.0])})
    vehicle = Series(gt.t, {"speed": gt["vx"], "handlebar": np.zeros(len(gt))})
    run = RunData(gt, Series.empty(), Series.empty(), Series.empty(), None, Series.empty(), setpoint=setpoint,
                  vehicle=vehicle, guard=guard_series(rows), actors=person(5.0 + FP.front + 0.9, 0.0), contacts=[])
    m = obstacle_metrics(run, V)
    assert m["protective_stops"] == 1 and m["stops_entered_by_motion"] == 1
    assert m["stop_latencies_ms"] == pytest.approx([10.0])
