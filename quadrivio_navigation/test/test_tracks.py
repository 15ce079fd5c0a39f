"""Moving obstacles tracked in the scans (tracks.py), and the guard acting on where they will be."""
import math

import numpy as np
import pytest

from quadrivio_config import from_mapping
from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.fields import Rays, ScanPoints, scan_points
from quadrivio_navigation.guard import STOP, Guard, GuardParams
from quadrivio_navigation.tracks import MotionTracker, SeenScan, TrackParams, clusters, seen_through


def raycast(pose, circles, mount=(1.2, 0.0), fov=math.radians(270.0), n=541, max_range=30.0, rng=None, noise=0.0):
    """A planar laser at ``mount`` (base_link) of a vehicle at ``pose`` (x, y, yaw, world)
    seeing circles (x, y, r, world): the returns' points in base_link, in ray order."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy = x + c * mount[0] - s * mount[1], y + s * mount[0] + c * mount[1]
    out = []
    for a in np.linspace(-fov / 2, fov / 2, n):
        dx, dy = math.cos(yaw + a), math.sin(yaw + a)
        best = max_range
        for cx, cy, r in circles:
            fx, fy = ox - cx, oy - cy
            b = fx * dx + fy * dy
            disc = b * b - (fx * fx + fy * fy - r * r)
            if disc >= 0.0:
                t = -b - math.sqrt(disc)
                if 0.0 < t < best:
                    best = t
        if best < max_range:
            if rng is not None:
                best += rng.normal(0.0, noise)
            out.append((mount[0] + best * math.cos(a), mount[1] + best * math.sin(a)))
    return np.array(out, dtype=float).reshape(-1, 2)


def ranges(pose, circles, mount=(1.2, 0.0), fov=math.radians(270.0), n=541, max_range=30.0, rng=None, noise=0.0,
           mixed=0.0, boxes=()):
    """The ranges (float32, +inf: nothing within max_range) of the laser of :func:`raycast`
    seeing circles and ``boxes`` (x, y, yaw, length, width; world); with ``mixed``, that share of the silhouettes' edges gets a mixed pixel (a return between
    the near and the far surface, as real scanners give)."""
    x, y, yaw = pose
    c, s = math.cos(yaw), math.sin(yaw)
    ox, oy = x + c * mount[0] - s * mount[1], y + s * mount[0] + c * mount[1]
    a = yaw + np.linspace(-fov / 2, fov / 2, n)
    dx, dy = np.cos(a)[:, None], np.sin(a)[:, None]
    cc = np.asarray(circles, dtype=float).reshape(-1, 3)
    fx, fy = ox - cc[:, 0], oy - cc[:, 1]
    b = fx * dx + fy * dy
    disc = b * b - (fx * fx + fy * fy - cc[:, 2] ** 2)
    hit = -b - np.sqrt(np.maximum(disc, 0.0))
    hit = np.where((disc >= 0.0) & (hit > 0.0), hit, np.inf)
    out = hit.min(axis=1) if len(cc) else np.full(n, np.inf)
    for bx, by, byaw, length, width in boxes:  # each side a segment: ray o + t d meets p + u e, u in [0, 1]
        cb, sb = math.cos(byaw), math.sin(byaw)
        corners = [(bx + cb * hl - sb * hw, by + sb * hl + cb * hw) for hl, hw in
                   ((length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2),
                    (length / 2, -width / 2))]
        for (px, py), (qx, qy) in zip(corners, corners[1:] + corners[:1]):
            ex, ey = qx - px, qy - py
            den = dx[:, 0] * ey - dy[:, 0] * ex
            with np.errstate(divide="ignore", invalid="ignore"):
                t = ((px - ox) * ey - (py - oy) * ex) / den
                u = ((px - ox) * dy[:, 0] - (py - oy) * dx[:, 0]) / den
            out = np.where((np.abs(den) > 1e-12) & (t > 0.0) & (u >= 0.0) & (u <= 1.0) & (t < out), t, out)
    out[out >= max_range] = np.inf
    if rng is not None:
        out = out + rng.normal(0.0, noise, n)
        if mixed:
            with np.errstate(invalid="ignore"):  # inf - inf between two rays that saw nothing
                d = np.diff(out)
            for e in np.flatnonzero(np.isfinite(d) & (np.abs(d) > 0.5)):
                if rng.random() < mixed:
                    near, far = min(out[e], out[e + 1]), max(out[e], out[e + 1])
                    out[e if out[e] > out[e + 1] else e + 1] = near + rng.uniform(0.1, 0.9) * (far - near)
    return out.astype(np.float32)


def scan(pose, circles, mount=(1.2, 0.0), fov=math.radians(270.0), n=541, max_range=30.0, rng=None, noise=0.0,
         mixed=0.0, boxes=()):
    """The scan of :func:`ranges` as the guard reads it: points and rays (range_min 0.05 m)."""
    rr = ranges(pose, circles, mount, fov, n, max_range, rng, noise, mixed, boxes)
    return scan_points(rr, -fov / 2, fov / (n - 1), 0.05, max_range, (mount[0], mount[1], 0.0), 20.0)


# scanners unlike ours (541 rays over 270 deg, 1 cm, 10 Hz here): (rays, noise [m], period [s], mixed pixels)
SCANNERS = {"ours": (541, 0.01, 0.1, 0.0), "fine_noisy": (1081, 0.03, 0.04, 0.5), "coarse": (271, 0.02, 0.05, 0.5)}


def _first_moving(circles_at, duration, speed=0.0, rays=True, scanner="ours", p=TrackParams(), boxes_at=None,
                  yaw_rate=0.0, tracker=None, each=None):
    """Drive a tracker at ``speed`` (turning at ``yaw_rate``) for ``duration`` seconds of a
    scanner's scans: the first time a track moves, how many scans had one, and the tracks
    refused (a centroid that moved where no scan saw anything move). ``each(tracker)`` is
    called after every scan."""
    n, noise, period, mixed = SCANNERS[scanner]
    tr = MotionTracker(p) if tracker is None else tracker
    rng = np.random.default_rng(7)
    first, scans = None, 0
    x = y = yaw = 0.0
    for k in range(int(round(duration / period))):
        t = period * k
        pose = (x, y, yaw)
        sp = scan(pose, circles_at(t), mount=(1.6, 0.0), n=n, rng=rng, noise=noise, mixed=mixed,
                  boxes=boxes_at(t) if boxes_at else ())
        pr = tr.update(t, sp.xy, pose, sp.rays if rays else None)
        if each is not None:
            each(tr)
        if pr.moving:
            scans += 1
            first = t if first is None else first
        x, y, yaw = x + speed * period * math.cos(yaw), y + speed * period * math.sin(yaw), yaw + yaw_rate * period
    return first, scans, tr.refused


def test_clusters_split_where_neighbours_are_apart():
    xy = np.array([[0, 0], [0.1, 0], [0.2, 0], [1.0, 0], [1.1, 0], [5, 5]], dtype=float)
    assert clusters(xy, 0.3) == [(0, 3), (3, 5), (5, 6)]
    assert clusters(np.zeros((0, 2)), 0.3) == []


def test_a_person_crossing_ahead_is_tracked_at_their_speed_and_predicted_across_the_path():
    tr = MotionTracker(TrackParams())
    found = None
    for k in range(12):
        t = 0.1 * k
        pose = (3.0 * t, 0.0, 0.0)  # the vehicle at 3 m/s along x
        person = (10.0, -3.0 + 1.4 * t, 0.3)  # crossing its path at 1.4 m/s
        pr = tr.update(t, raycast(pose, [person]), pose)
        if pr.moving and found is None:
            found = t
    # moving once its centroid has travelled min_travel (0.3 m) plus its radius: 0.4 s at 1.4 m/s
    assert found is not None and found <= 0.45, found
    (k,) = [k for k in tr.tracks if k.moving]
    assert k.vx == pytest.approx(0.0, abs=0.15)
    assert k.vy == pytest.approx(1.4, abs=0.15)
    # in base_link: the copies reach across y = 0 (the path) ahead of the vehicle
    pr = tr.prediction
    assert pr.moving == 1 and np.all(pr.speed == pytest.approx(1.4, abs=0.15))
    near_path = pr.xy[np.abs(pr.xy[:, 1]) < 0.5]
    assert len(near_path) and np.all(near_path[:, 0] > 4.0)
    assert pr.xy[:, 1].max() == pytest.approx(-3.0 + 1.4 * 1.1 + 2.0 * 1.4, abs=0.6)


def test_standing_trees_seen_from_a_turning_noisy_vehicle_never_move():
    rng = np.random.default_rng(3)
    trees = [(x, y, 0.15) for x in np.arange(2.0, 40.0, 1.5) for y in (-2.5, 2.5)]
    tr = MotionTracker(TrackParams())
    x = y = yaw = 0.0
    moving = 0
    for k in range(100):
        t = 0.1 * k
        w = 0.15 * math.sin(0.5 * t)  # weaving, 3 m/s
        x, y, yaw = x + 0.3 * math.cos(yaw), y + 0.3 * math.sin(yaw), yaw + 0.1 * w
        pr = tr.update(t, raycast((x, y, yaw), trees, rng=rng, noise=0.02), (x, y, yaw))
        moving += pr.moving
    assert moving == 0
    assert len(tr.tracks) > 5


@pytest.mark.parametrize("scanner", sorted(SCANNERS))
def test_trunks_passed_close_and_a_far_row_seen_through_gaps_never_move(scanner):
    """The orchard's trunks are 1.15 m wide. Passed 0.3 m away at 2 m/s, the visible arc turns
    around each (and the field of view cuts it); the far rows show slivers through the near
    row's gaps that slide along them. Their centroids travel further than their visible size
    at a steady pace: the centroid test alone takes them for things that move (it did in
    the orchard: false stops). Nothing stands where a scan saw through: with the rays, none
    moves, on our scanner and on a finer, noisier, faster one and a coarser one, both with
    mixed pixels at the silhouettes."""
    trees = [(x, y, 0.57) for x in np.arange(4.0, 25.0, 3.0) for y in (-1.45, 1.45)]
    trees += [(x, y, 0.57) for x in np.arange(4.0, 25.0, 1.5) for y in (-7.5, 7.5)]
    first, scans, refused = _first_moving(lambda t: trees, 7.0, speed=2.0, rays=False, scanner=scanner)
    assert scans >= 5, "the centroids alone no longer take trunks for things that move: the case tests little"
    assert refused == 0  # without rays nothing is refused
    first, scans, refused = _first_moving(lambda t: trees, 7.0, speed=2.0, scanner=scanner)
    assert (first, scans) == (None, 0)
    assert refused >= 5  # counted: the guard's diagnostics report it


@pytest.mark.parametrize("scanner", sorted(SCANNERS))
@pytest.mark.parametrize("heading", [0.0, math.pi / 2, math.pi, -math.pi / 2])
def test_a_person_crossing_walking_away_or_coming_is_found_as_early_with_the_rays(heading, scanner):
    """Whichever way a person walks (across the path, straight away from the laser, straight at
    it), points of theirs enter space an earlier scan saw through, or leave space the scan now
    sees through: the rays' test finds them moving at the same scan as the centroids alone
    (within two scans on a coarse scanner with mixed pixels), with trunks around them."""
    trees = [(x, y, 0.57) for x in np.arange(4.0, 30.0, 3.0) for y in (-3.0, 3.0)]
    u, v = math.cos(heading), math.sin(heading)
    x0, y0 = 12.0 - 2.0 * u, -2.0 * v

    def circles(t):
        return trees + [(x0 + 1.4 * u * t, y0 + 1.4 * v * t, 0.3)]

    # standing: what comes and goes along a ray has no other clue
    without, _, _ = _first_moving(circles, 2.5, rays=False, scanner=scanner)
    with_rays, _, _ = _first_moving(circles, 2.5, scanner=scanner)
    assert without is not None and without <= 0.6, without
    assert with_rays is not None and with_rays <= without + 2 * SCANNERS[scanner][2] + 1e-9, (with_rays, without)


@pytest.mark.parametrize("scanner", sorted(SCANNERS))
@pytest.mark.parametrize("heading", [math.pi / 2, 3 * math.pi / 4, math.pi])
def test_a_machine_crossing_or_coming_is_tracked_by_its_leading_corner(heading, scanner):
    """A tractor (4 x 2 m) at 4 m/s across the path 8 m ahead, at an angle, or straight at
    the vehicle. Crossing, its cluster reaches further from its centroid than its travel in a
    window, and the centroid wanders as the side in view grows and shrinks (shape changes
    restart its history): the centroid alone finds it moving late, if ever. An end of the
    cluster, its leading corner, moves on a line at its speed: it is moving within half a
    second of being in view, at its speed and heading, on every scanner."""
    u, v = math.cos(heading), math.sin(heading)
    x0, y0 = 10.0 - 7.0 * u, -7.0 * v

    def boxes(t):
        return [(x0 + 4.0 * u * t, y0 + 4.0 * v * t, heading, 4.0, 2.0)]

    tr = MotionTracker(TrackParams())
    first, scans, _ = _first_moving(lambda t: [], 1.6, speed=2.0, scanner=scanner, boxes_at=boxes, tracker=tr)
    assert first is not None and first <= 0.5, first
    assert scans >= 0.5 * 1.6 / SCANNERS[scanner][2], scans  # and then most of the time
    (k,) = [k for k in tr.tracks if k.moving]
    assert math.hypot(k.vx, k.vy) == pytest.approx(4.0, rel=0.15)
    assert abs(math.remainder(math.atan2(k.vy, k.vx) - heading, 2 * math.pi)) < math.radians(10.0)
    centroid, _, _ = _first_moving(lambda t: [], 1.6, speed=2.0, scanner=scanner, boxes_at=boxes,
                                   p=TrackParams(end_travel=100.0))
    if heading == math.pi / 2:
        assert centroid is None or centroid >= first + 0.3, (centroid, first)


@pytest.mark.parametrize("scanner", sorted(SCANNERS))
@pytest.mark.parametrize("speed", [8.0, 11.0])
def test_a_car_on_a_farm_road_is_believed_where_max_speed_allows_it(speed, scanner):
    """A car (4.5 x 1.8 m) crossing 10 m ahead at 8 and 11 m/s (30-40 km/h on a farm road;
    a running deer is as fast). At the default ``max_speed`` (12 m/s) it is moving within half
    a second of being in view, at its speed within 15 %. With ``max_speed`` 5 it is never a
    moving thing at its speed: the guard would stop for where the car is, not where it goes
    (the figure eight crossed at 8 m/s: 10 contacts in 20 runs at 5 m/s, none at 12;
    bench/HISTORY.md, "track_max_speed 12")."""
    x0, y0 = 10.0, -9.0

    def boxes(t):
        return [(x0, y0 + speed * t, math.pi / 2, 4.5, 1.8)]

    tr = MotionTracker(TrackParams())
    assert TrackParams().max_speed >= 12.0
    first, _, _ = _first_moving(lambda t: [], 1.2, speed=2.0, scanner=scanner, boxes_at=boxes, tracker=tr)
    assert first is not None and first <= 0.5, first
    (k,) = [k for k in tr.tracks if k.moving]
    assert math.hypot(k.vx, k.vy) == pytest.approx(speed, rel=0.15)
    speeds = []  # a walking-pace limit: never a moving thing at the car's speed
    slow = TrackParams(max_speed=5.0)
    _first_moving(lambda t: [], 1.2, speed=2.0, scanner=scanner, boxes_at=boxes, p=slow,
                  each=lambda tr: speeds.extend(math.hypot(k.vx, k.vy) for k in tr.tracks if k.moving))
    assert all(v <= slow.max_speed for v in speeds), speeds


@pytest.mark.parametrize("scanner", sorted(SCANNERS))
def test_parked_machines_walls_and_trunks_passed_close_never_move(scanner):
    """Standing things whose ends slide as the vehicle passes them turning, at 3 m/s: a wall
    along the path (the field of view cuts it: its end moves with the vehicle), a parked
    machine 0.5 m beside the path (the corner in view changes), a wall across the path ahead
    seen past a box, trunks beside the path. Nothing stands where a scan saw through: none
    moves. Without the rays' test, ends alone are never used."""
    boxes = [(10.0, -2.6, 0.0, 14.0, 0.3), (8.0, 2.2, 0.1, 4.0, 2.0), (22.0, 0.0, math.pi / 2, 0.3, 12.0),
             (15.0, 1.5, 0.5, 1.0, 1.0)]
    trees = [(x, 4.5, 0.3) for x in np.arange(3.0, 20.0, 1.5)]
    first, scans, _ = _first_moving(lambda t: trees, 5.0, speed=3.0, yaw_rate=0.04, scanner=scanner,
                                    boxes_at=lambda t: boxes)
    assert (first, scans) == (None, 0)


def test_what_a_scan_saw_through_by_hand():
    """seen_through on a 360-degree laser mounted upside down (its angles turn the other way)
    1 m ahead of base_link, the vehicle at (10, 5) heading +y: rays 1 degree apart, every ray
    free to 8 m except two and some unknown (NaN). A point is through when none of the rays
    passing within seen_margin of it (widened by seen_angle and one ray) stopped short of
    seen_margin beyond it, and at least half of them are known."""
    n = 360
    free = np.full(n, 8.0)
    inc = math.radians(1.0)
    amin = -math.pi
    # the laser's angle a points along (cos a, -sin a) in base_link; base_link's +x is the map's +y
    i_left = int(round((math.radians(-90.0) - amin) / inc))  # a = -90 deg: base_link +y, the map's -x
    free[i_left] = 3.0  # a return at 3 m
    i_right = int(round((math.radians(90.0) - amin) / inc))  # toward base_link -y, the map's +x
    free[i_right] = math.nan  # one unknown ray (a dropout)
    free[i_right + 20:i_right + 40] = math.nan  # and a run of them, 20-40 deg further round
    rays = Rays((1.0, 0.0), (1.0, 0.0, 0.0, -1.0), amin, inc, free)
    sc = SeenScan(0.0, 10.0, 6.0, 0.0, 1.0, rays)  # the laser at (10, 6): base_link (1, 0) of a vehicle at (10, 5)
    p = TrackParams(seen_margin=0.15, seen_angle=0.01)

    def through(x, y):
        return seen_through(sc, np.array([[x, y]]), p)

    assert through(10.0, 11.0) == 1  # 5 m ahead (base_link +x): every ray there free to 8 m
    assert through(10.0, 13.9) == 0  # 7.9 m: not 0.15 m short of 8 m
    assert through(8.0, 6.0) == 1  # 2 m to base_link's left, along the ray with the return at 3 m: seen through
    assert through(7.1, 6.0) == 0  # 2.9 m: not 0.15 m short of that return
    assert through(6.9, 6.0) == 0  # 3.1 m: behind it
    # beside it: the rays passing within 0.15 m of a point 3.1 m away span asin(0.15 / 3.1) =
    # 2.77 deg each side, plus seen_angle (0.57 deg) and one ray: 4.35 rays, out to the next
    # whole ray: 5 rays aside the return's ray still counts, 6 rays aside it does not
    assert through(6.9, 6.0 + 3.1 * math.tan(math.radians(5.0))) == 0
    assert through(6.9, 6.0 + 3.1 * math.tan(math.radians(6.0))) == 1
    assert through(12.0, 6.0) == 1  # along the unknown ray: its neighbours saw through, it says nothing
    # 2 m along the laser's angle a = 120 deg, in the run of unknown rays: base_link 2 (cos a, -sin a),
    # the map's (10 + 2 sin a, 6 + 2 cos a); fewer than half of the rays near it are known
    a = math.radians(120.0)
    assert through(10.0 + 2.0 * math.sin(a), 6.0 + 2.0 * math.cos(a)) == 0
    assert through(10.0 - 2.0 * math.sin(a), 6.0 + 2.0 * math.cos(a)) == 1  # at -120 deg, all known and free
    free[i_right] = 1.5  # a return at 1.5 m there instead
    assert through(12.0, 6.0) == 0
    assert through(10.0, 1.0) == 1  # behind the vehicle, across angle_min = -180 deg (the wrap)
    assert through(10.0, 6.0 + 0.1) == 0  # closer to the laser than seen_margin: nothing to see through
    assert seen_through(sc, np.array([[10.0, 11.0], [8.0, 6.0], [6.9, 6.0]]), p) == 2
    assert seen_through(SeenScan(0.0, 10.0, 6.0, 0.0, 1.0, Rays((1.0, 0.0), (0.0, 0.0, 0.0, 0.0), amin, inc, free)),
                        np.array([[10.0, 11.0]]), p) == 0  # a laser seen edge-on (no plane): nothing


def test_a_wall_is_not_tracked_and_a_jumping_centroid_is_no_motion():
    p = TrackParams()
    tr = MotionTracker(p)
    wall = np.column_stack([np.full(140, 5.0), np.linspace(-7, 7, 140)])  # further than max_extent from its centroid
    for k in range(10):  # the vehicle drives at 3 m/s along a wall that seems to move with it
        tr.update(0.1 * k, wall, (0.3 * k, 0.0, 0.0))
    assert tr.tracks == [] and tr.prediction.moving == 0
    # a post half hidden now and then: its centroid jumps 0.2 m back and forth
    tr = MotionTracker(p)
    for k in range(10):
        c = 0.2 * (k % 2)
        post = np.column_stack([np.full(5, 6.0), c + np.linspace(-0.1, 0.1, 5)])
        tr.update(0.1 * k, post, (0.0, 0.0, 0.0))
        assert tr.prediction.moving == 0


def test_no_horizon_no_tracking():
    tr = MotionTracker(TrackParams(horizon=0.0))
    for k in range(6):
        tr.update(0.1 * k, raycast((0, 0, 0), [(8.0, -2 + 1.4 * 0.1 * k, 0.3)]), (0.0, 0.0, 0.0))
    assert tr.tracks == [] and tr.prediction.moving == 0


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


def _crossing_run(vehicle, horizon):
    """The vehicle at 3 m/s; a person steps out 1.75 m beside its path 7 m ahead and crosses at
    1.4 m/s. The guard's first STOP or SLOW below 2 m/s: (time, reason), with the person then."""
    g = Guard(from_mapping(GuardParams, {"track_horizon": horizon}, "test"), vehicle)
    x, first = 0.0, None
    for k in range(0, 150):
        t = 0.02 * k
        g.on_state(t, 3.0, 0.0)
        if k % 5 == 0:
            person = (8.9, -2.8 + 1.4 * t, 0.3)  # 7 m ahead of the bumper, 1.75 m beside the swept path
            g.on_scan("scan/front", t, scan((x, 0.0, 0.0), [person], mount=(1.7, 0.0)))
            g.on_scan("scan/rear", t, ScanPoints(np.zeros((0, 2)), 541, 0, 0))
        d = g.decide(t, 3.0, 0.0)
        if first is None and (d.action == STOP or d.limit < 2.0):
            first = (t, d.reason, d.action)
        x += 3.0 * 0.02
    return first


def test_the_guard_slows_for_a_person_about_to_cross_before_they_are_in_the_path(vehicle):
    with_tracks = _crossing_run(vehicle, 2.0)
    without = _crossing_run(vehicle, 0.0)
    assert with_tracks is not None and "moving obstacle (1.4 m/s" in with_tracks[1], with_tracks
    # the person enters the swept path (half width + padding 0.75 m, their radius 0.3) at about
    # t = (2.8 - 1.05) / 1.4 = 1.25 s; by then the static guard has not reacted yet
    assert with_tracks[0] < 0.8
    assert without is None or without[0] > with_tracks[0] + 0.4, without


def test_a_thing_that_moved_and_stopped_is_kept_further_away():
    p = TrackParams()
    tr = MotionTracker(p)
    for k in range(30):  # walks 1.4 m/s for 1 s, then stands in the path
        t = 0.1 * k
        y = -2.5 + 1.4 * min(t, 1.0)
        pr = tr.update(t, raycast((0.0, 0.0, 0.0), [(8.0, y, 0.3)], mount=(1.7, 0.0)), (0.0, 0.0, 0.0))
    assert pr.moving == 0 and len(pr.xy) > 0 and np.all(pr.speed == 0.0)
    (k,) = tr.tracks
    assert k.moved and not k.moving
    # four copies of each (of at most max_points) points, clearance away along the axes
    assert len(pr.xy) % 4 == 0 and len(pr.xy) <= 4 * p.max_points
    pts = raycast((0.0, 0.0, 0.0), [(8.0, -1.1, 0.3)], mount=(1.7, 0.0))
    assert pr.xy[:, 0].min() == pytest.approx(pts[:, 0].min() - p.clearance, abs=0.05)
    # a post that never moved gets none
    tr = MotionTracker(p)
    for k in range(30):
        pr = tr.update(0.1 * k, raycast((0.0, 0.0, 0.0), [(8.0, 0.0, 0.3)], mount=(1.7, 0.0)), (0.0, 0.0, 0.0))
    assert len(pr.xy) == 0


def test_the_guards_track_keys_are_the_trackers_defaults():
    """GuardParams' track_* defaults (config/guard.yaml states them: test_config_files) are
    TrackParams' own."""
    assert GuardParams().tracks() == TrackParams()


def _predict_reference(p, xy, a, b, ux, uy, speed):
    """The prediction's loops as they were written first (and as the C++ guard runs them)."""
    out_xy, out_v = [], []
    n = b - a
    k = min(n, p.max_points)
    idx = [a + (i * (n - 1)) // (k - 1) for i in range(k)] if k > 1 else [a]
    steps = max(1, int(math.ceil(speed * p.horizon / p.step))) if speed > 0.0 else 0
    cl = p.clearance
    for j in range(steps + 1):
        tau = p.horizon * j / steps if steps else 0.0
        for i in idx:
            x, y = float(xy[i, 0]) + ux * tau, float(xy[i, 1]) + uy * tau
            if j > 0:
                out_xy.append((x, y))
                out_v.append(speed)
            if cl > 0.0:
                out_xy += [(x + cl, y), (x - cl, y), (x, y + cl), (x, y - cl)]
                out_v += [speed] * 4
    return np.array(out_xy, dtype=float).reshape(-1, 2), np.array(out_v, dtype=float)


def test_the_prediction_in_arrays_is_the_loops_bit_for_bit():
    """MotionTracker._predict builds its points with numpy: the same points, in the same order,
    to the last bit, as the loops it replaced, on random clusters, speeds (standing included),
    directions and parameters (no clearance, one point, more points than max_points)."""
    rng = np.random.default_rng(11)
    for case in range(300):
        p = TrackParams(horizon=float(rng.choice([1.0, 2.0, 2.5])), step=float(rng.choice([0.25, 0.4, 1.0])),
                        clearance=float(rng.choice([0.0, 0.15, 0.3])), max_points=int(rng.integers(1, 12)))
        xy = rng.uniform(-8.0, 8.0, (40, 2))
        a = int(rng.integers(0, 39))
        b = int(rng.integers(a + 1, 41))
        speed = 0.0 if case % 4 == 0 else float(rng.uniform(0.05, 3.0))
        ux, uy = (0.0, 0.0) if speed == 0.0 else tuple(rng.normal(0.0, 1.5, 2))
        out_xy, out_v = [], []
        MotionTracker(p)._predict(xy, a, b, ux, uy, speed, out_xy, out_v)
        got_xy = np.concatenate(out_xy) if out_xy else np.zeros((0, 2))
        got_v = np.concatenate(out_v) if out_v else np.zeros(0)
        want_xy, want_v = _predict_reference(p, xy, a, b, ux, uy, speed)
        assert got_xy.shape == want_xy.shape and np.array_equal(got_xy, want_xy), case
        assert np.array_equal(got_v, want_v), case
