"""Metrics of runs with obstacles and actors, against the ground truth.

* ``collisions``: contacts of the vehicle with any body but the ground, from the
  simulator's own contact points (``/ground_truth/contacts``), each with time, body and
  speed at impact (``collision_events``);
* ``min_clearance_m``: the smallest distance, over the run, from the true (unpadded)
  footprint to any actor, scenario obstacle or map body (the cylinders and boxes the
  simulator builds from the map's occupied cells: :func:`map_points`); a point ``p`` in the
  footprint's frame ``(u, w)`` is ``hypot(max(-rear - u, 0, u - front), max(-right - w, 0,
  w - left))`` from the rectangle;
* ``protective_stops``: the guard's protective stops (transitions to STOP in the
  protective field); ``fault_stops``: its fail-safe stops of a moving vehicle (a FAULT
  while standing, before the first scan or pose, stops nothing); ``zone_stops``;
* ``false_stops``: protective stops at a moment when, in the ground truth, no body lay in
  the footprint swept from the true pose as the guard swept it (its direction, from the
  measured handlebar toward the requested one) over the protective distance plus
  ``tolerance``, nor entered within the next ``anticipation`` seconds (the guard's
  ``track_horizon``: it stops for where a moving obstacle will be) the field of the vehicle
  driving on, that footprint swept ``speed * tau`` further after ``tau`` seconds: nothing
  was there to stop for; ``anticipated_stops``: those for an actor that was not in that
  field yet but would have entered it had the vehicle not stopped (a person about to cross
  just beyond the field), by its true motion or by the way it moved at the stop (its
  velocity over the last ``MOTION_DT`` s held: a person walking at the path who stopped
  short of it, which no guard can know beforehand); both null when a recording without
  ground truth has stops (they cannot be judged there);
* ``time_blocked_s``: sim time the guard held the vehicle (STOP, HOLD, FAULT, or a speed
  limit below 0.05 m/s) while the request was to move;
* ``stop_latencies_ms``: for each protective stop, from the stamp of the scan that showed
  the obstacle in the protective field to the first guarded setpoint with speed 0 and the
  brake that the recorder received (the PLCClient forwards it on arrival). A stop decided
  on a scan the guard had already judged without a stop (it showed the obstacle in the
  warning field; the vehicle then drove into the protective one, and the guard's decision
  on a later request found it there) has no such scan: its latency runs from that decision
  (the request's period, 20 ms, is the most it can be late); counted in
  ``stops_entered_by_motion``. Found on dog_runs_out: a dog seen 0.68-0.77 m along the path
  in the warning field at 34.90 s, the vehicle measured 0.84 -> 0.95 m/s while its limit
  fell to 0.3, the stop at 35.04 s on a request: 140 ms "after the scan";
* ``stop_to_standstill_s``: for each stop (protective or fail-safe), from the decision to
  the measured wheel speed below 0.1 m/s.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional

import numpy as np

STOP, HOLD, FAULT = 2, 3, 4


def _outline_points(shape: str, x: float, y: float, yaw: float, length: float, width: float,
                    spacing: float = 0.05) -> np.ndarray:
    """Points every ``spacing`` m on a body's outline (map frame)."""
    if shape == "cylinder":
        r = 0.5 * length
        n = max(16, int(math.ceil(2 * math.pi * r / spacing)))
        a = 2 * math.pi * np.arange(n) / n
        return np.column_stack([x + r * np.cos(a), y + r * np.sin(a)])
    hx, hy = 0.5 * length, 0.5 * width
    corners = [(hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy), (hx, hy)]
    pts = []
    for (ax, ay), (bx, by) in zip(corners, corners[1:]):
        n = max(2, int(math.ceil(math.hypot(bx - ax, by - ay) / spacing)))
        u = np.arange(n) / n
        pts.append(np.column_stack([ax + u * (bx - ax), ay + u * (by - ay)]))
    p = np.concatenate(pts)
    c, s = math.cos(yaw), math.sin(yaw)
    return np.column_stack([x + c * p[:, 0] - s * p[:, 1], y + s * p[:, 0] + c * p[:, 1]])


MOTION_DT = 0.2  # [s] an actor's velocity at a stop: its motion over this long before it


def actors_moving_on(actors, t: float, tau: float, dt: float = MOTION_DT) -> np.ndarray:
    """Every actor's outline points ``tau`` s after ``t`` had each kept the velocity it had
    over the ``dt`` s before ``t`` (what an observer at ``t`` could extrapolate)."""
    now, before = actors_at(actors, t), actors_at(actors, t - dt)
    if len(now) != len(before):
        return now
    return now + (now - before) * (tau / dt)


def actors_at(actors, t: float) -> np.ndarray:
    """Every actor's and obstacle's outline points at time ``t`` (positions interpolated)."""
    if not actors:
        return np.zeros((0, 2))
    times = np.array([a[0] for a in actors])
    i = int(np.searchsorted(times, t))
    i0, i1 = max(0, min(i - 1, len(actors) - 1)), max(0, min(i, len(actors) - 1))
    snap0, snap1 = actors[i0][1], actors[i1][1]
    u = 0.0 if i0 == i1 or times[i1] == times[i0] else (t - times[i0]) / (times[i1] - times[i0])
    u = min(max(u, 0.0), 1.0)
    by_name = {b[0]: b for b in snap1}
    pts = []
    for b in snap0:
        name, kind, shape, x, y, yaw, length, width = b
        b1 = by_name.get(name, b)
        pts.append(_outline_points(shape, x + u * (b1[3] - x), y + u * (b1[4] - y), yaw, length, width))
    return np.concatenate(pts) if pts else np.zeros((0, 2))


# The simulator's map bodies by default (quadrivio_sim/config/sim.yaml, map:): cells at or above
# OCCUPIED, a cylinder around each blob no wider than TREE_SIZE, boxes covering the others. A
# run that recorded /ground_truth/map_bodies gives the bodies its simulator built instead.
OCCUPIED, TREE_SIZE = 65, 1.2
_BODIES: Dict[int, tuple] = {}  # id(grid or bodies) -> (them, points): one map, many runs and stops


def map_bodies(blocks) -> list:
    """The simulator's :class:`quadrivio_navigation.maps.Block` s as RunData's map_bodies
    (name, kind, shape, x, y, yaw, length, width), named as on /ground_truth/map_bodies."""
    return [(f"map_{i}", "map", b.kind, b.x, b.y, b.yaw, b.size_x, b.size_y) for i, b in enumerate(blocks)]


def map_points(grid, bodies: Optional[list] = None, occupied: int = OCCUPIED,
               tree_size: float = TREE_SIZE) -> np.ndarray:
    """Points every 5 cm on the outlines of the map's bodies, map frame: ``bodies`` (the
    simulator's own, (name, kind, shape, x, y, yaw, length, width) as on
    /ground_truth/map_bodies) or, without them, those the simulator builds from the map's
    occupied cells with its default settings (:func:`quadrivio_navigation.maps.obstacles_from_grid`).
    Not the cells' centres: a tree's cylinder reaches the blob's farthest cell corner, 0.14-0.31 m
    beyond the outermost centre toward the lane on the orchard's map, so clearances and
    false stops judged by the centres were off by that much."""
    source = bodies if bodies is not None else grid
    if source is None:
        return np.zeros((0, 2))
    cached = _BODIES.get(id(source))
    if cached is not None and cached[0] is source:
        return cached[1]
    if bodies is None:
        from quadrivio_navigation.maps import obstacles_from_grid

        bodies = map_bodies(obstacles_from_grid(grid, occupied, tree_size))
    pts = [_outline_points(shape, x, y, yaw, length, width) for _, _, shape, x, y, yaw, length, width in bodies]
    out = np.concatenate(pts) if pts else np.zeros((0, 2))
    _BODIES.clear()  # one map at a time: a campaign's worker keeps the last
    _BODIES[id(source)] = (source, out)
    return out


def rectangle_distance(fp, x: float, y: float, yaw: float, pts: np.ndarray) -> np.ndarray:
    """Distance of each point from the footprint at pose (x, y, yaw) (0 inside)."""
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = pts[:, 0] - x, pts[:, 1] - y
    u = c * dx + s * dy
    w = -s * dx + c * dy
    du = np.maximum(np.maximum(-fp.rear - u, 0.0), u - fp.front)
    dw = np.maximum(np.maximum(-fp.right - w, 0.0), w - fp.left)
    return np.hypot(du, dw)


COVER = 4  # discs along the footprint for the bounds of min_clearance and metrics.touching


def cover_discs(fp, xs: np.ndarray, ys: np.ndarray, yaws: np.ndarray, grow: float = 0.0, n: int = COVER):
    """``n`` discs covering the footprint grown by ``grow`` on every side, at each pose
    (arrays): their centres ([(x, y)] of arrays, one pair per disc, along the footprint) and
    their common radius (each covers its ``1/n`` of the rectangle's length)."""
    part = 0.5 * (fp.front + fp.rear + 2.0 * grow) / n
    radius = math.hypot(part, 0.5 * (fp.left + fp.right) + grow)
    across = 0.5 * (fp.left - fp.right)
    c, s = np.cos(yaws), np.sin(yaws)
    centres = []
    for k in range(n):
        along = -fp.rear - grow + (2 * k + 1) * part
        centres.append((xs + c * along - s * across, ys + s * along + c * across))
    return centres, radius


def min_clearance(gt, fp, actors, grid, stride: int = 1, bodies: Optional[list] = None) -> Optional[float]:
    """The smallest footprint-to-body distance over the ground truth [m] (None: no bodies)."""
    fixed = map_points(grid, bodies)  # on the bodies' outlines
    if not actors and len(fixed) == 0 or len(gt) == 0:
        return None
    reach = fp.circumscribed_radius + 3.0
    best = math.inf
    idx = range(0, len(gt), stride)
    if actors:
        for i in idx:
            x, y, yaw, t = float(gt["x"][i]), float(gt["y"][i]), float(gt["yaw"][i]), float(gt.t[i])
            pts = actors_at(actors, t)
            if len(pts):
                best = min(best, float(rectangle_distance(fp, x, y, yaw, pts).min()))
    if len(fixed):
        # The poses nearest the bodies first, each against the points that could beat the
        # best so far. No footprint point is nearer a body than a body is to the nearest of
        # COVER discs (centres along the footprint, each covering its part) less their
        # radius: once that bound reaches the best distance found, no pose left can beat it;
        # and no point farther than the best plus the circumscribed radius from base_link
        # can. The same minimum as every pose against every point in reach (the test), for a
        # fraction of the poses and points: an orchard run 0.13 s -> 0.01 s.
        from scipy.spatial import cKDTree

        tree = cKDTree(fixed)
        xs, ys, yaws = (np.asarray(gt[k], float)[idx.start:idx.stop:idx.step] for k in ("x", "y", "yaw"))
        centres, disc = cover_discs(fp, xs, ys, yaws)
        bound = np.full(len(xs), math.inf)
        for cx, cy in centres:
            d, _ = tree.query(np.column_stack([cx, cy]))
            bound = np.minimum(bound, d - disc - 1e-9)  # a nanometre for rounding
        for j in np.argsort(bound, kind="stable"):
            if not bound[j] < best:
                break  # sorted: no pose left can beat it
            x, y, yaw = float(xs[j]), float(ys[j]), float(yaws[j])
            near = tree.query_ball_point((x, y), min(reach, best + fp.circumscribed_radius + 1e-9))
            if near:
                best = min(best, float(rectangle_distance(fp, x, y, yaw, fixed[near]).min()))
    return best if math.isfinite(best) else None


def _at(series, key: str, t: float) -> float:
    if len(series) == 0:
        return math.nan
    i = min(int(np.searchsorted(series.t, t)), len(series) - 1)
    return float(series[key][i])


def obstacle_metrics(run, vehicle, tolerance: float = 0.5, anticipation: float = 2.0) -> Dict[str, object]:
    """The obstacle keys of ``metrics.json`` (see the module docstring); {} without a guard,
    actors or contacts in the run."""
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.fields import free_distance, sweep

    out: Dict[str, object] = {}
    g = run.guard
    if run.contacts is not None:
        out["collisions"] = len(run.contacts)
        out["collision_events"] = [{"t": c[0], "body": c[1], "kind": c[2], "speed_mps": c[3]} for c in run.contacts]
    fp = Footprint.from_vehicle(vehicle)
    if run.actors or run.map is not None or run.map_bodies:
        out["min_clearance_m"] = min_clearance(run.ground_truth, fp, run.actors, run.map, bodies=run.map_bodies)
    if len(g) == 0:
        return out
    action = g["action"]
    prev = np.concatenate([[-1], action[:-1]])
    entered = np.flatnonzero((action != prev))
    stops = [i for i in entered if action[i] == STOP and g["zone"][i] == 0]
    out["protective_stops"] = len(stops)
    moving = np.abs(g["measured"]) >= 0.1 if "measured" in g.cols else np.ones(len(g), dtype=bool)
    out["fault_stops"] = int(sum(1 for i in entered if action[i] == FAULT and moving[i]))  # a stop, not a start-up
    out["zone_stops"] = int(sum(1 for i in entered if action[i] == STOP and g["zone"][i] == 1))
    fixed = map_points(run.map, run.map_bodies)
    false, anticipated, latencies, by_motion = 0, 0, [], 0
    sp = run.setpoint
    pad = Footprint.from_vehicle(vehicle, 0.15)
    for i in stops:
        t = float(g.t[i])
        gt = run.ground_truth
        if len(gt):
            x, y, yaw = _at(gt, "x", t), _at(gt, "y", t), _at(gt, "yaw", t)
            direction = int(g["direction"][i]) or 1
            # the guard's own sweep: from the measured handlebar toward the requested one
            h0 = float(g["handlebar_measured"][i]) if "handlebar_measured" in g.cols else math.nan
            h1 = float(g["handlebar_requested"][i]) if "handlebar_requested" in g.cols else math.nan
            if not math.isfinite(h0):
                h0 = _at(run.vehicle, "handlebar", t) if len(run.vehicle) else 0.0
                h0 = 0.0 if not math.isfinite(h0) else h0
            h1 = h0 if not math.isfinite(h1) else h1
            length = float(g["protective"][i]) + tolerance
            speed = abs(float(g["measured"][i])) if "measured" in g.cols else 1.0
            c, s = math.cos(yaw), math.sin(yaw)

            def in_field(pts, further: float = 0.0) -> bool:
                if len(pts) == 0:
                    return False
                poses = sweep(direction, h0, h1, vehicle.steering.max_rate, speed, length + further, 0.05,
                              vehicle.wheelbase, vehicle.steering.ratio)
                local = np.column_stack([c * (pts[:, 0] - x) + s * (pts[:, 1] - y),
                                         -s * (pts[:, 0] - x) + c * (pts[:, 1] - y)])
                return math.isfinite(free_distance(pad, poses, local, 0.05).distance)

            pts = actors_at(run.actors, t)
            if len(fixed):
                pts = np.concatenate([pts, fixed]) if len(pts) else fixed
            if not in_field(pts):
                taus = np.arange(0.1, anticipation + 1e-9, 0.1)
                later = run.actors and (any(in_field(actors_at(run.actors, t + tau), speed * tau) for tau in taus)
                                        or any(in_field(actors_moving_on(run.actors, t, tau), speed * tau)
                                               for tau in taus))
                if later:
                    anticipated += 1
                else:
                    false += 1
        scan = float(g["scan_stamp"][i])
        if len(sp) and math.isfinite(scan) and scan > 0.0:
            start = scan
            if np.any((g["scan_stamp"][:i] == scan) & (g["action"][:i] != STOP)):
                start = float(g.t[i])  # judged before without a stop: the vehicle drove into the field
                by_motion += 1
            after = np.flatnonzero((sp.t >= start) & (sp["speed"] == 0.0) & (sp["brake"] >= 0.99))
            if len(after):
                latencies.append(1e3 * (float(sp.t[after[0]]) - start))
    # judged against the ground truth: a recording without it cannot say (null, not 0)
    judged = len(run.ground_truth) > 0 or not stops
    out["false_stops"] = false if judged else None
    out["anticipated_stops"] = anticipated if judged else None
    out["stop_latencies_ms"] = latencies
    out["stops_entered_by_motion"] = by_motion
    # from each stop's decision (protective or fail-safe) to the vehicle's standstill
    standstill = []
    veh = run.vehicle
    for i in [i for i in entered if action[i] in (STOP, FAULT)]:
        t = float(g.t[i])
        if len(veh):
            after = np.flatnonzero((veh.t >= t) & (np.abs(veh["speed"]) < 0.1))
            if len(after):
                standstill.append(float(veh.t[after[0]]) - t)
    out["stop_to_standstill_s"] = standstill
    req = g["requested"]
    blocked = ((action == STOP) | (action == HOLD) | (action == FAULT) | (g["limit"] < 0.05)) & (np.abs(req) > 0.1)
    dt = np.diff(g.t, append=g.t[-1])
    out["time_blocked_s"] = float(np.sum(dt[blocked]))
    return out


def stop_list(run) -> List[tuple]:
    """(t, x, y, action) of each stop of the guard (STOP or FAULT), for plots: at the true
    position, or at the estimated one in a recording without ground truth."""
    g = run.guard
    gt = run.ground_truth if len(run.ground_truth) else run.estimate
    if len(g) == 0 or len(gt) == 0:
        return []
    action = g["action"]
    prev = np.concatenate([[-1], action[:-1]])
    out = []
    for i in np.flatnonzero((action != prev) & ((action == STOP) | (action == FAULT))):
        t = float(g.t[i])
        out.append((t, _at(gt, "x", t), _at(gt, "y", t), int(action[i])))
    return out
