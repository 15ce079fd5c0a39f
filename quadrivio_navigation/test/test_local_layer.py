"""The local obstacle layer's marking, clearing, decay and rolling on synthetic scans
(quadrivio_navigation.local_layer), with costmap_2d's obstacle-layer semantics."""
import math

import numpy as np
import pytest

from quadrivio_navigation.local_layer import LocalLayer, LocalLayerParams, dem_ground

BEARINGS = np.radians(np.arange(-135.0, 135.01, 1.0))


@pytest.fixture(params=[False, True], ids=["numpy", "native"])
def native(request):
    """The layer's rays traced in numpy (the reference) and in native code (the default where
    the workspace is built, as it is for make test)."""
    return request.param


def value_at(layer, x, y):
    row, col, ok = layer.cells(np.array([[x, y]]))
    assert ok[0]
    return int(layer.grid_values()[row[0], col[0]])


def test_marks_returns_and_clears_the_rays_to_them(native):
    layer = LocalLayer(LocalLayerParams(size=20.0, resolution=0.1, obstacle_range=6.0, raytrace_range=8.0), native=native)
    ranges = np.full(len(BEARINGS), np.inf)
    ahead = np.abs(BEARINGS) < np.radians(5)
    ranges[ahead] = 5.0 / np.cos(BEARINGS[ahead])  # a wall 5 m ahead, +-0.44 m wide
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, ranges)
    assert value_at(layer, 5.02, 0.0) == 100
    assert value_at(layer, 2.5, 0.0) == 0  # cleared (seen free) on the way
    assert value_at(layer, 7.0, 0.0) == -1  # behind the wall: unknown
    assert value_at(layer, 0.0, 8.5) == -1  # beyond the raytrace range (a sideways ray saw nothing: 8 m)
    assert value_at(layer, 0.0, 7.5) == 0
    # beyond obstacle_range: marks nothing, still clears
    layer2 = LocalLayer(LocalLayerParams(size=20.0, obstacle_range=4.0, raytrace_range=10.0), native=native)
    layer2.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, ranges)
    assert not layer2.occupied().any()
    assert value_at(layer2, 4.5, 0.0) == 0


def test_a_moved_obstacle_is_cleared_by_the_rays_through_it(native):
    layer = LocalLayer(LocalLayerParams(size=20.0, decay=0.0), native=native)
    r = np.full(len(BEARINGS), np.inf)
    i = int(np.argmin(np.abs(BEARINGS)))
    r[i] = 4.0
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, r)
    assert value_at(layer, 4.02, 0.0) == 100
    layer.add_scan(2.0, (0.0, 0.0, 0.0), BEARINGS, np.full(len(BEARINGS), np.inf))  # gone
    assert value_at(layer, 4.02, 0.0) == 0


def test_marks_decay_when_not_seen_again(native):
    layer = LocalLayer(LocalLayerParams(size=20.0, decay=2.0), native=native)
    r = np.full(len(BEARINGS), np.inf)
    r[int(np.argmin(np.abs(BEARINGS)))] = 4.0
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, r)
    narrow = np.radians([90.0])  # later scans look elsewhere (sideways only)
    layer.add_scan(2.5, (0.0, 0.0, 0.0), narrow, np.array([np.inf]))
    assert value_at(layer, 4.02, 0.0) == 100
    layer.add_scan(3.5, (0.0, 0.0, 0.0), narrow, np.array([np.inf]))
    assert value_at(layer, 4.02, 0.0) != 100


def test_rolling_keeps_marks_in_place():
    layer = LocalLayer(LocalLayerParams(size=10.0, resolution=0.1, decay=0.0))
    r = np.full(len(BEARINGS), np.inf)
    r[int(np.argmin(np.abs(BEARINGS)))] = 3.0
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, r)
    before = layer.marked_points()
    layer.recentre(1.37, -0.8)  # the vehicle moved
    after = layer.marked_points()
    assert len(before) == len(after) == 1
    assert after[0] == pytest.approx(before[0])
    layer.recentre(30.0, 0.0)  # far: the mark has left the grid
    assert not layer.occupied().any()


def test_bad_ranges_rep117(native):
    layer = LocalLayer(LocalLayerParams(size=20.0), native=native)
    r = np.full(len(BEARINGS), np.nan)  # every reading invalid: nothing marked, nothing cleared
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, r)
    assert (layer.grid_values() == -1).all()
    r[135] = -np.inf  # too close: marks the scanner's own cell
    layer.add_scan(1.1, (0.0, 0.0, 0.0), BEARINGS, r)
    assert value_at(layer, 0.01, 0.01) == 100


def test_returns_on_the_dem_are_ground_not_obstacles(native):
    # terrain rising ahead at 15 %; a level scanner 0.55 m up meets it at ~3.7 m
    def heights(x, y):
        return 0.15 * np.maximum(np.asarray(x), 0.0)

    layer = LocalLayer(LocalLayerParams(size=20.0), native=native)
    ranges = np.full(len(BEARINGS), np.inf)
    front = np.abs(BEARINGS) < np.radians(30)
    ranges[front] = 0.55 / 0.15 / np.cos(BEARINGS[front])
    ground = dem_ground(heights, (0.0, 0.0, 0.55), np.eye(3), 0.15)
    layer.add_scan(1.0, (0.0, 0.0, 0.0), BEARINGS, ranges, ground=ground)
    assert not layer.occupied().any()
    assert layer.ground_returns == int(front.sum())
    # a post standing on that slope is still an obstacle
    ranges[135] = 2.0
    layer.add_scan(2.0, (0.0, 0.0, 0.0), BEARINGS, ranges, ground=ground)
    assert value_at(layer, 2.02, 0.0) == 100


def _same_grids(a: LocalLayer, b: LocalLayer, what: str) -> None:
    assert a.origin == b.origin, what
    assert np.array_equal(a.stamp, b.stamp, equal_nan=True), what
    assert np.array_equal(a.seen, b.seen), what
    assert a.ground_returns == b.ground_returns, what


def test_the_native_trace_marks_and_clears_as_the_python_one():
    """Random scans through both: grids of several sizes and resolutions (0.3 m does not
    divide the ranges), scanners anywhere (outside the grid too), headings, fields of view and
    angular steps unlike ours, REP 117's NaN and +-inf, returns past both ranges, a sloped DEM
    taking some returns for the ground, and the grid rolling between scans: the same cells,
    bit for bit."""
    rng = np.random.default_rng(7)
    for case in range(60):
        p = LocalLayerParams(size=float(rng.choice([6.0, 12.5, 24.0])), resolution=float(rng.choice([0.05, 0.1, 0.3])),
                             obstacle_range=float(rng.uniform(1.0, 12.0)), raytrace_range=float(rng.uniform(1.0, 15.0)),
                             decay=float(rng.choice([0.0, 2.0])))
        ref, nat = LocalLayer(p, native=False), LocalLayer(p, native=True)
        n_rays = int(rng.integers(1, 1100))
        fov = float(rng.uniform(0.1, 2.0 * math.pi))
        bearings = -0.5 * fov + fov * np.arange(n_rays) / max(1, n_rays - 1)
        if rng.random() < 0.3:
            bearings = -bearings  # a scanner turning the other way
        slope = float(rng.uniform(-0.2, 0.2))
        x, y = rng.uniform(-5.0, 5.0, 2)
        for k in range(4):
            x, y = x + rng.normal(0.0, 2.0), y + rng.normal(0.0, 2.0)
            sensor = (x, y, float(rng.uniform(-math.pi, math.pi)))
            r = rng.uniform(-0.5, 20.0, n_rays)
            u = rng.random(n_rays)
            r[u < 0.1] = np.nan
            r[(u >= 0.1) & (u < 0.25)] = np.inf
            r[(u >= 0.25) & (u < 0.3)] = -np.inf
            ground = None
            if rng.random() < 0.5:
                ground = dem_ground(lambda gx, gy: slope * np.asarray(gx), (x, y, 0.55), np.eye(3), 0.15)
            for layer in (ref, nat):
                layer.add_scan(float(k), sensor, bearings, r, ground)
            _same_grids(ref, nat, f"case {case}, scan {k}")
        assert ref.seen.any() or not np.isfinite(ref.stamp).any()


def test_update_cost_is_small():
    import time
    layer = LocalLayer(LocalLayerParams())
    rng = np.random.default_rng(0)
    ranges = rng.uniform(0.5, 30.0, len(BEARINGS))
    ranges[rng.random(len(BEARINGS)) < 0.3] = np.inf
    t0 = time.perf_counter()
    for k in range(20):
        layer.add_scan(float(k), (0.1 * k, 0.0, 0.0), BEARINGS, ranges)
    per = (time.perf_counter() - t0) / 20
    assert per < 0.05  # a loose bound for a loaded machine; the benchmark measures it (bench_obstacles)
    assert math.isfinite(per)


def test_the_ground_tolerance_grows_with_range_by_the_attitudes_error():
    """A braking vehicle pitched 5 deg nose down whose attitude says 3.5: its scan plane meets
    the level ground 6.1 m ahead, where the estimated plane is 0.16 m above it: the ground with
    0.02 m per metre of range, an obstacle with a flat 0.15 m tolerance; 1 m ahead the plane is
    0.47 m up, and a body there stays an obstacle."""
    import math

    import numpy as np

    from quadrivio_navigation.local_layer import dem_ground

    level = lambda x, y: np.zeros_like(np.asarray(x, dtype=float))  # noqa: E731
    pitch = math.radians(3.5)  # the attitude's (REP-103: positive is nose down)
    R = np.array([[math.cos(pitch), 0.0, math.sin(pitch)], [0.0, 1.0, 0.0], [-math.sin(pitch), 0.0, math.cos(pitch)]])
    ahead = 0.53 / math.tan(math.radians(5.0))  # where it meets the ground at a true pitch of 5 deg
    flat = dem_ground(level, (0.0, 0.0, 0.53), R, 0.15)
    grows = dem_ground(level, (0.0, 0.0, 0.53), R, 0.15, 0.02)
    r = np.array([ahead])
    assert not flat(np.zeros(1), r)[0] and grows(np.zeros(1), r)[0]
    # 1 m ahead the plane is 0.47 m up: a body there is no ground
    assert not grows(np.zeros(1), np.array([1.0]))[0]


def test_the_ground_tolerance_grows_with_the_poses_uncertainty_on_a_slope_only():
    """A pose 0.6 m off on a 25 % bump face draws the ground 0.15 m off the DEM: with a slack
    of 2 sds (0.3 m each: 0.6 m) times the DEM's gradient there (0.25) a return 0.25 m off is
    the ground; on level ground the slack adds nothing; and the cap keeps a person's legs
    (0.4 m up) an obstacle however uncertain the pose (a slack of 1.2 m would take them)."""
    import numpy as np

    from quadrivio_navigation.local_layer import dem_ground

    face = lambda x, y: 0.25 * np.asarray(x, dtype=float)  # noqa: E731
    level = lambda x, y: np.zeros_like(np.asarray(x, dtype=float))  # noqa: E731
    R = np.eye(3)
    ray = (np.zeros(1), np.array([3.0]))  # straight ahead 3 m, the scanner at x = 0
    for off, slack, cap, expect in ((0.25, 0.0, 0.3, False), (0.25, 0.6, 0.3, True), (0.40, 1.2, np.inf, True),
                                    (0.40, 1.2, 0.3, False)):
        z = 0.25 * 3.0 + off
        got = dem_ground(face, (0.0, 0.0, z), R, 0.15, 0.0, slack, cap)(*ray)[0]
        assert got == expect, (off, slack, cap)
    assert not dem_ground(level, (0.0, 0.0, 0.25), R, 0.15, 0.0, 5.0)(*ray)[0]  # level: no slack
    assert dem_ground(level, (0.0, 0.0, 0.14), R, 0.15, 0.0, 5.0)(*ray)[0]


def march(dem, pos, R, bearings, start):
    """The true scan of a scanner at ``pos`` with rotation ``R`` over the terrain ``dem``:
    each ray marched from ``start`` m in 2 mm steps to where it meets the ground (NaN: not
    within 12 m)."""
    ranges = np.full(len(bearings), np.nan)
    s = np.arange(start, 12.0, 0.002)
    for k, b in enumerate(bearings):
        p = np.asarray(pos)[:, None] + (R @ np.array([np.cos(b), np.sin(b), 0.0]))[:, None] * s
        below = np.flatnonzero(p[2] <= dem(p[0], p[1]))
        if len(below):
            ranges[k] = s[below[0]]
    return ranges


def test_bump_faces_seen_from_an_estimate_off_more_than_its_sd_are_ground_with_the_sd_floor():
    """Rough ground (bumps 0.1 m high every 2 m on a 6 % slope): the vehicle truly at the origin,
    its estimate 0.5 m off with a reported sd of 0.1 m. Its laser, pitched down, meets the
    ground 4-6 m ahead. From the estimate some of those returns look like obstacles; with the
    guard's sd floor (0.5 m) none does, and a post 0.57 m tall stays an obstacle."""
    import numpy as np

    from quadrivio_navigation.local_layer import scanner_pose_3d, terrain_ground

    def dem(x, y):
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return 0.06 * x + 0.1 * np.sin(np.pi * x) * np.cos(0.8 * np.pi * y)

    t_b, R_b = (1.6, 0.0, 0.3), np.eye(3)
    pitch = 0.09  # nose down (REP 103)
    pos, R = scanner_pose_3d(dem, 0.0, 0.0, 0.0, 0.0, pitch, 0.3, t_b, R_b)
    bearings = np.linspace(-0.6, 0.6, 121)
    ranges = march(dem, pos, R, bearings, 0.5)
    hit = np.isfinite(ranges)
    assert hit.sum() > 100 and np.nanmax(ranges) < 8.0
    est = (0.5, 0.0, 0.0, 0.1)  # 0.5 m off, sd 0.1
    args = (dem, est, 0.0, pitch, 0.3, t_b, R_b, 0.15, 0.0, 2.0, 0.3)
    plain = terrain_ground(*args)(bearings[hit], ranges[hit])
    floored = terrain_ground(*args, sd_min=0.5)(bearings[hit], ranges[hit])
    assert not plain.all(), "the test needs returns that the plain sd gets wrong"
    assert floored.all()
    # a post: a level scan's return 3 m ahead lies at the scan plane's height over the ground
    # (above the 0.3 m cap): an obstacle, floor or not
    level = (dem, est, 0.0, 0.0, 0.3, t_b, R_b, 0.15, 0.0, 2.0, 0.3)
    p0, R0 = scanner_pose_3d(dem, *est[:3], 0.0, 0.0, 0.3, t_b, R_b)
    assert p0[2] - dem(p0[0] + 3.0, 0.0) > 0.4
    assert not terrain_ground(*level, sd_min=0.5)(np.array([0.0]), np.array([3.0]))[0]


def test_base_on_wheels_by_hand():
    """Flat ground: base_link at the wheel radius. A level vehicle on a 10 % grade along x:
    the wheels' mean height is the grade's at their centroid (half the wheelbase ahead), the
    gradient 0.1. One wheel on a 0.2 m step: the base rises a quarter of it."""
    import numpy as np

    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.local_layer import base_on_wheels, wheel_centres

    v = load_vehicle()
    w, r, level = wheel_centres(v), v.wheel_radius, np.eye(3)
    assert np.allclose(w, [[1.25, 0.4895], [1.25, -0.4895], [0.0, 0.4665], [0.0, -0.4665]])
    z, g = base_on_wheels(lambda x, y: np.full(np.shape(x), 2.0), 3.0, 4.0, level, r, w)
    assert z == pytest.approx(2.0 + r) and g == pytest.approx(0.0)
    z, g = base_on_wheels(lambda x, y: 0.1 * np.asarray(x), 3.0, 4.0, level, r, w)
    assert z == pytest.approx(0.1 * (3.0 + 0.625) + r) and g == pytest.approx(0.1)
    step = lambda x, y: np.where((np.asarray(x) > 3.5) & (np.asarray(y) > 4.0), 0.2, 0.0)  # noqa: E731
    z, _ = base_on_wheels(step, 3.0, 4.0, level, r, w)  # under the front left wheel only
    assert z == pytest.approx(r + 0.05)


def test_ground_seen_from_a_pose_off_on_bumps_is_ground_when_the_vehicle_stands_on_its_wheels():
    """Bumps 0.12 m from crest to trough every 1.6 m: the vehicle truly at 17 places along
    them, pitched 11 deg nose down (its front laser meets the ground about 2 m ahead), its
    estimate 0.36 m behind (sd 0.15 m; the guard's floor 0.5 m), as on the rough terrain at
    3 m/s where a false stop came from it. Drawn with base_link over the DEM at its origin,
    the scanner's height is off by the bump's face under it and some ground returns look
    like obstacles; standing on its wheels, with that height's own uncertainty, none does.
    A post 3 m ahead of a level scan stays an obstacle everywhere."""
    import numpy as np

    from quadrivio_description.frames import rpy_matrix
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.local_layer import base_on_wheels, terrain_ground, wheel_centres

    v = load_vehicle()
    wheels, wr = wheel_centres(v), v.wheel_radius
    mount = v.sensors["laser_front"]
    t_b, R_b = np.array(mount.xyz), np.array(rpy_matrix(tuple(mount.rpy)))

    def dem(x, y):
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        return 0.06 * np.sin(2.0 * np.pi * x / 1.6) * np.cos(np.pi * y / 1.3)

    pitch, bearings = 0.2, np.linspace(-0.6, 0.6, 61)
    R = np.array(rpy_matrix((0.0, pitch, 0.0)))
    old_wrong = new_wrong = posts_missed = returns = 0
    for x0 in np.linspace(0.0, 1.6, 17):
        pos = np.array([x0, 0.0, base_on_wheels(dem, x0, 0.0, R, wr, wheels)[0]]) + R @ t_b
        ranges = march(dem, pos, R @ R_b, bearings, 0.3)
        hit = np.isfinite(ranges)
        returns += int(hit.sum())
        est = (x0 + 0.36, 0.0, 0.0, 0.15)
        args = (dem, est, 0.0, pitch, wr, t_b, R_b, 0.15, 0.0, 2.0, 0.3)
        old_wrong += int((~terrain_ground(*args, sd_min=0.5)(bearings[hit], ranges[hit])).sum())
        new_wrong += int((~terrain_ground(*args, sd_min=0.5, wheels=wheels)(bearings[hit], ranges[hit])).sum())
        level = (dem, est, 0.0, 0.0, wr, t_b, R_b, 0.15, 0.0, 2.0, 0.3)
        posts_missed += int(terrain_ground(*level, sd_min=0.5, wheels=wheels)(np.array([0.0]), np.array([3.0]))[0])
    assert returns > 900
    assert old_wrong > 10, "the test needs returns that the base over the DEM gets wrong"
    assert new_wrong == 0
    assert posts_missed == 0
