"""Moving obstacles in the lasers: clusters tracked from scan to scan, and where they will be.

A guard that treats every laser return as standing still stops for a person only once the
person is in the vehicle's path: a person stepping out between two trees 2 m ahead of a
vehicle at 3 m/s is inside its stopping distance before any field holds them. Safety laser
scanners do not predict; nav2's collision monitor's "approach" action predicts only the
robot. This module predicts the obstacles too, with nothing but the scans and the vehicle's
own motion (no map, no localization: the guard must not depend on the estimate):

* **ego-motion**: the vehicle's pose in a local odometric frame, integrated from the
  measured speed and handlebar (the sweep's bicycle model, :mod:`quadrivio_navigation.fields`);
* **clusters**: a scan's points in ray order, split where two neighbours are more than
  ``cluster_gap`` apart; a cluster wider than ``max_extent`` (a long wall, a tree row seen
  along, the ground) or further than ``max_range`` is not tracked (the cost);
* **tracks**: each cluster's centroid in the odometric frame, matched to the track whose
  position predicted to the scan's time is nearest (greedy, nearest pair first, within
  ``gate`` plus ``max_speed`` times the time since the track was seen); a cluster whose
  size changes by more than ``shape_change`` (occlusion, two things merging) restarts its
  centroid's history;
* **velocity**: the least-squares line through the track's centroids over the last
  ``window`` seconds (at least ``min_obs`` of them over ``min_span``); it counts only when
  every centroid lies within ``max_residual`` of the line (a centroid that jumps is not a
  motion), the speed lies between ``min_speed`` and ``max_speed``, and the line travels
  further than ``min_travel`` plus the cluster's own radius: the centroid of a thing seen
  from a moving vehicle, or partly hidden behind its neighbour (a tree behind a tree along
  a row), wanders across its visible face, by up to its size, without the thing moving.
  Clusters of fewer than ``min_points`` returns are not tracked;
* **ends**: a machine's centroid wanders by more than it travels (a tractor crossing shows
  a side that grows and shrinks), but its corners do not: failing the centroid, a track
  moves when an end of its cluster (its first or last return) lies on a line over the
  longest run of the window it can (shape changes do not restart it), each within
  ``max_residual`` plus the rays' spacing at its range (the end is the last ray that hit:
  up to a spacing short of the corner), at a speed within the limits, travelling
  ``end_travel``. Standing things' ends slide too (a wall's where the field of view cuts
  it, a trunk's round it, one behind another's along the near one): ends count only with
  the rays' test below, over the end's run;
* **seen through** (with the scans' rays): a centroid that travels is not enough, because
  the visible face of a standing thing can slide further than its visible size: a trunk
  1.2 m wide passed 0.3 m away shows an arc that turns around it, a trunk of the far row
  seen through a gap of the near one shows the sliver the gap lets through, and the laser's
  field of view cuts a thing it passes. None of them can do what only motion does: be where
  an earlier scan saw through, or leave where the scan now sees through. A point lies where
  a scan saw through when the rays of that scan passing within ``seen_margin`` of it
  (widened by ``seen_angle`` and one ray) reached ``seen_margin`` beyond it: none of them
  stopped short (-inf: at ``range_min``), and at least half of them are known (+inf: to
  ``range_max``; a NaN ray, the scanner's dropout in rain or dust, says nothing either way). A track moves only when at least
  ``seen_points`` of its cluster's points (at most ``max_points``, evenly picked) lie where
  the scan at the start of its window saw through, or as many of that scan's cluster's
  points lie where the current scan sees through (the detection-and-tracking literature's
  free-space evidence; Petrovskaya and Thrun 2009, Wang et al. 2007). The rays that count
  are those passing within ``seen_margin`` of the point: a point is a few centimetres off
  where it is (range noise, the odometry), and seen from another side a trunk's noisy
  return can lie just outside its silhouette. Scans given without rays skip this test;
* **prediction**: a moving track's points (at most ``max_points`` of them) copied along its
  velocity every ``step`` metres over the next ``horizon`` seconds, in the scan's base_link:
  the guard treats them as returns, so the whole stretch the obstacle will cross is
  something the vehicle must be able to stop short of (conservative: it does not ask when
  the vehicle would get there);
* **clearance**: a thing that has moved while tracked (a dog that ran into the lane and
  stands there, a person who stopped) may move again: its points and their copies are
  guarded ``clearance`` further away than a tree's, as four copies offset by it along
  base_link's axes (the directions the footprint's sides face when driving straight).

Pure Python with sequential sums (no numpy reductions on the values that decide): the
roscpp guard (``include/quadrivio_navigation/guard_core.h``) does the same arithmetic in
the same order and is cross-tested against this module (``test/test_guard_native.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import List, Optional, Tuple

import numpy as np

from .fields import Rays


@dataclass(frozen=True)
class TrackParams:
    horizon: float = 2.0  # [s] how far ahead a moving obstacle is predicted; 0: none
    cluster_gap: float = 0.3  # [m]
    max_extent: float = 6.0  # [m] a cluster's largest distance from its centroid (an 11 m machine from a corner)
    max_range: float = 15.0  # [m]
    gate: float = 0.3  # [m]
    max_speed: float = 12.0  # [m/s]
    min_speed: float = 0.5  # [m/s]
    window: float = 0.8  # [s]
    min_obs: int = 3
    min_span: float = 0.15  # [s]
    max_residual: float = 0.08  # [m]
    min_travel: float = 0.3  # [m] beyond the cluster's own size, over the window
    end_travel: float = 0.9  # [m] an end of the cluster (its first or last return), over its run on a line
    min_points: int = 3
    shape_change: float = 0.25  # [m]
    coast: float = 0.5  # [s]
    step: float = 0.1  # [m]
    max_points: int = 8
    clearance: float = 0.2  # [m] kept from a thing that has moved, beyond the guard's padding
    seen_margin: float = 0.15  # [m] seen through: the rays passing within this of a point reached this far beyond
    seen_angle: float = 0.01  # [rad] ...those rays widened by this, plus one ray (the odometry's heading error)
    seen_points: int = 2  # points that entered or left space seen through, for a track to move
    max_tracks: int = 200


@dataclass
class Track:
    ident: int
    hist: List[Tuple[float, float, float]]  # (t, x, y) of the centroid, odometric frame
    radius: float  # [m] the cluster's largest distance from its centroid
    last_t: float
    since: float = -math.inf  # the centroid's history starts here (a shape change restarts it; the ends' does not)
    vx: float = 0.0
    vy: float = 0.0
    moving: bool = False
    moved: bool = False  # moving at some scan of its life
    shapes: List[np.ndarray] = field(default_factory=list)  # per hist entry: its picked points (odometric frame),
    # the cluster's first and last return (its ends) among them


@dataclass
class Prediction:
    """Where the moving obstacles of one scan will be, in that scan's base_link."""
    xy: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    speed: np.ndarray = field(default_factory=lambda: np.zeros(0))  # [m/s] of the track each point is from
    moving: int = 0  # tracks predicted


def clusters(xy: np.ndarray, gap: float) -> List[Tuple[int, int]]:
    """[start, end) index ranges of the points (in ray order) split where neighbours are more
    than ``gap`` apart."""
    n = len(xy)
    if n == 0:
        return []
    d = np.diff(xy, axis=0)
    breaks = np.flatnonzero(d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] > gap * gap) + 1
    edges = [0] + [int(b) for b in breaks] + [n]
    return [(edges[i], edges[i + 1]) for i in range(len(edges) - 1)]


def centroids(xy: np.ndarray, ranges: List[Tuple[int, int]]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each cluster's mean (x, y) and largest distance from it. The sums are differences of
    the running (sequential) sums over all the points, as the C++ tracker computes them."""
    starts = np.array([a for a, _ in ranges], dtype=int)
    ends = np.array([b for _, b in ranges], dtype=int)
    csx = np.concatenate([[0.0], np.cumsum(xy[:, 0])])
    csy = np.concatenate([[0.0], np.cumsum(xy[:, 1])])
    n = (ends - starts).astype(float)
    cx = (csx[ends] - csx[starts]) / n
    cy = (csy[ends] - csy[starts]) / n
    counts = ends - starts
    dx = xy[:, 0] - np.repeat(cx, counts)
    dy = xy[:, 1] - np.repeat(cy, counts)
    r = np.maximum.reduceat(np.sqrt(dx * dx + dy * dy), starts)
    return cx, cy, r


def _fit(hist, p: TrackParams, tol: Optional[List[float]] = None) -> Optional[Tuple[float, float]]:
    """The velocity of the least-squares line through the centroids (t, x, y), or None when
    one lies further from it than ``max_residual`` (or its own ``tol``)."""
    n = len(hist)
    if n < p.min_obs or hist[-1][0] - hist[0][0] < p.min_span:
        return None
    st = sx = sy = 0.0
    for t, x, y in hist:
        st += t
        sx += x
        sy += y
    mt, mx, my = st / n, sx / n, sy / n
    stt = stx = sty = 0.0
    for t, x, y in hist:
        dt = t - mt
        stt += dt * dt
        stx += dt * (x - mx)
        sty += dt * (y - my)
    if stt <= 0.0:
        return None
    vx, vy = stx / stt, sty / stt
    for i, (t, x, y) in enumerate(hist):
        ex, ey = x - (mx + vx * (t - mt)), y - (my + vy * (t - mt))
        e = p.max_residual if tol is None else tol[i]
        if ex * ex + ey * ey > e * e:
            return None
    return vx, vy


@dataclass(frozen=True)
class SeenScan:
    """A scan's rays placed in the odometric frame: the laser at (ox, oy), base_link's heading
    (c, s) = (cos, sin) of the vehicle's yaw then."""
    t: float
    ox: float
    oy: float
    c: float
    s: float
    rays: Rays


def picks(a: int, b: int, k: int) -> List[int]:
    """At most ``k`` indices of a..b-1, evenly spread, the first and the last included."""
    n = b - a
    k = min(n, k)
    return [a + (i * (n - 1)) // (k - 1) for i in range(k)] if k > 1 else [a]


def seen_through(scan: SeenScan, pts: np.ndarray, p: TrackParams) -> int:
    """How many of the points (odometric frame) lie where ``scan`` saw through: of the rays
    passing within ``seen_margin`` of the point (widened by ``seen_angle`` and one ray), none
    stopped short of ``seen_margin`` beyond it and at least half are known (not NaN), and all
    those rays are in the scan (a scan all around wraps). A point a few centimetres off a
    trunk's silhouette (range noise seen from another side) is not through: the rays beside
    it hit the trunk."""
    r_ = scan.rays
    m00, m01, m10, m11 = r_.m
    det = m00 * m11 - m01 * m10
    free = r_.free
    n = len(free)
    if abs(det) < 1e-6 or n == 0 or r_.increment == 0.0:
        return 0
    full = abs(r_.increment) * n >= 2.0 * math.pi - 0.5 * abs(r_.increment)  # all around: the rays wrap
    count = 0
    for qx, qy in pts:
        dx, dy = float(qx) - scan.ox, float(qy) - scan.oy
        bx, by = scan.c * dx + scan.s * dy, -scan.s * dx + scan.c * dy  # base_link then
        u, v = (m11 * bx - m01 * by) / det, (-m10 * bx + m00 * by) / det  # the laser's plane
        rng = math.sqrt(u * u + v * v)
        if rng <= p.seen_margin:  # at the laser: nothing to see through
            continue
        a = math.atan2(v, u)
        # the rays passing within seen_margin of the point (its noise, the odometry's), seen_angle more, one ray more
        w = 1.0 + (p.seen_angle + math.asin(p.seen_margin / rng)) / abs(r_.increment)
        fi = None
        for cand in (a, a + 2.0 * math.pi, a - 2.0 * math.pi):
            f = (cand - r_.angle_min) / r_.increment
            if -0.5 <= f <= n - 0.5:
                fi = f
                break
        if fi is None:
            continue
        lo, hi = int(math.floor(fi - w)), int(math.ceil(fi + w))
        if (lo < 0 or hi > n - 1) and not full:
            continue
        need = rng + p.seen_margin
        known = 0
        for i in range(lo, hi + 1):
            f = free[i % n]
            if f != f:  # NaN: unknown
                continue
            if f < need:
                break
            known += 1
        else:
            if 2 * known >= hi - lo + 1:
                count += 1
    return count


class MotionTracker:
    """One scanner's tracks; :meth:`update` with each scan, its prediction in ``self.prediction``."""

    def __init__(self, p: TrackParams) -> None:
        self.p = p
        self.tracks: List[Track] = []
        self.next_id = 0
        self.last_stamp = -math.inf
        self.prediction = Prediction()
        self.scans: List[SeenScan] = []  # the window's scans with rays, oldest first
        self.refused = 0  # (track, scan) pairs whose centroid moved but that no scan saw move, over the tracker's life

    def reset(self) -> None:
        self.tracks = []
        self.last_stamp = -math.inf
        self.prediction = Prediction()
        self.scans = []

    def update(self, stamp: float, xy: np.ndarray, ego: Tuple[float, float, float],
               rays: Optional[Rays] = None) -> Prediction:
        """A scan's points (base_link, ray order) at ``stamp`` with the vehicle's odometric pose
        ``ego`` (x, y, yaw) then, and the scan's ``rays`` (None: no test of what was seen
        through). A scan not newer than the last is ignored."""
        p = self.p
        if p.horizon <= 0.0 or not stamp > self.last_stamp:
            return self.prediction
        self.last_stamp = stamp
        ex, ey, eyaw = ego
        c, s = math.cos(eyaw), math.sin(eyaw)
        if rays is None:
            self.scans = []
        else:
            ox, oy = rays.origin
            self.scans = [sc for sc in self.scans if sc.t >= stamp - p.window]
            self.scans.append(SeenScan(stamp, ex + c * ox - s * oy, ey + s * ox + c * oy, c, s, rays))
        found = []  # (x, y in odom, radius, a, b)
        ranges = clusters(xy, p.cluster_gap)
        if ranges:
            cx, cy, rad = centroids(xy, ranges)
            keep = np.flatnonzero([b - a >= p.min_points for a, b in ranges] & (rad <= p.max_extent) &
                                  (cx * cx + cy * cy <= p.max_range * p.max_range))
            for j in keep:
                bx, by, r = float(cx[j]), float(cy[j]), float(rad[j])
                found.append((ex + c * bx - s * by, ey + s * bx + c * by, r) + ranges[j])
        live = [k for k in self.tracks if stamp - k.last_t <= p.coast]
        pairs = []
        if live and found:
            # every track against every cluster at once (elementwise: the same arithmetic as the loops in C++)
            dts = np.array([stamp - k.last_t for k in live])
            px = np.array([k.hist[-1][1] for k in live]) + np.array([k.vx for k in live]) * dts
            py = np.array([k.hist[-1][2] for k in live]) + np.array([k.vy for k in live]) * dts
            gate = p.gate + p.max_speed * dts
            dx = np.array([f[0] for f in found])[None, :] - px[:, None]
            dy = np.array([f[1] for f in found])[None, :] - py[:, None]
            d = np.sqrt(dx * dx + dy * dy)
            ti, ci = np.nonzero(d <= gate[:, None])
            dd = d[ti, ci]
            order = np.lexsort((ci, ti, dd))  # by distance, then track, then cluster
            pairs = [(float(dd[j]), int(ti[j]), int(ci[j])) for j in order]
        used_t, used_c = set(), set()
        matched = {}
        for d, ti, ci in pairs:
            if ti in used_t or ci in used_c:
                continue
            used_t.add(ti)
            used_c.add(ci)
            matched[ci] = live[ti]
        tracks = [k for ti, k in enumerate(live) if ti not in used_t]
        out_xy, out_v, moving = [], [], 0
        for ci, f in enumerate(found):
            fx, fy, r, a, b = f
            k = matched.get(ci)
            if k is None:
                k = Track(self.next_id, [], r, stamp)
                self.next_id += 1
            if abs(r - k.radius) > p.shape_change:
                k.since = stamp
            keep = [i for i, h in enumerate(k.hist) if h[0] >= stamp - p.window]
            pk = picks(a, b, p.max_points)
            bx, by = xy[pk, 0].astype(float), xy[pk, 1].astype(float)
            shape = np.column_stack([ex + c * bx - s * by, ey + s * bx + c * by])
            k.hist = [k.hist[i] for i in keep] + [(stamp, fx, fy)]
            k.shapes = [k.shapes[i] for i in keep] + [shape]
            k.radius, k.last_t = r, stamp
            first = next(i for i, h in enumerate(k.hist) if h[0] >= k.since)
            v = _fit(k.hist[first:], p)
            speed = 0.0 if v is None else math.sqrt(v[0] * v[0] + v[1] * v[1])
            k.moving = (v is not None and p.min_speed <= speed <= p.max_speed and
                        speed * (k.hist[-1][0] - k.hist[first][0]) >= p.min_travel + r)
            if k.moving and rays is not None:
                k.moving = self._moved_through(k, first)
                self.refused += not k.moving
            if not k.moving and rays is not None:
                for end in (0, -1):
                    ve = self._end_moves(k, end)
                    if ve is not None:
                        v, speed, k.moving = ve, math.sqrt(ve[0] * ve[0] + ve[1] * ve[1]), True
                        break
            k.vx, k.vy = v if v is not None else (0.0, 0.0)
            k.moved = k.moved or k.moving
            tracks.append(k)
            if k.moving:
                moving += 1
                self._predict(xy, a, b, c * k.vx + s * k.vy, -s * k.vx + c * k.vy, speed, out_xy, out_v)
            elif k.moved:
                self._predict(xy, a, b, 0.0, 0.0, 0.0, out_xy, out_v)
        tracks.sort(key=lambda k: k.ident)
        self.tracks = tracks[-p.max_tracks:]
        self.prediction = Prediction(np.concatenate(out_xy) if out_xy else np.zeros((0, 2)),
                                     np.concatenate(out_v) if out_v else np.zeros(0), moving)
        return self.prediction

    def _moved_through(self, k: Track, i: int) -> bool:
        """Whether track ``k``'s cluster entered space the scan of its ``i``-th observation (the
        start of the run that moved) saw through, or left space the current scan sees through."""
        p = self.p
        first = next((sc for sc in self.scans if sc.t == k.hist[i][0]), None)
        if first is None:
            return False
        return (seen_through(first, k.shapes[-1], p) >= p.seen_points or
                seen_through(self.scans[-1], k.shapes[i], p) >= p.seen_points)

    def _end_moves(self, k: Track, end: int) -> Optional[Tuple[float, float]]:
        """The velocity of track ``k``'s cluster's end ``end`` (0: its first return, -1: its
        last) if it moves, else None. Its run is the longest stretch up to now of the window
        (shape changes included) over which the end lies on a line (``_fit``), each within
        ``max_residual`` plus the rays' spacing at its range (the end is the last ray that hit
        the thing: up to a spacing short of its corner, more on a face seen obliquely, taken up
        to 60 deg); it moves when the line's speed is within the limits, it travels
        ``end_travel`` over the run, and the cluster entered or left space seen through over
        it (:meth:`_moved_through`)."""
        p = self.p
        pts, tol = [], []
        for h, sh in zip(k.hist, k.shapes):
            sc = next((sc for sc in self.scans if sc.t == h[0]), None)
            if sc is None:
                return None
            x, y = float(sh[end][0]), float(sh[end][1])
            pts.append((h[0], x, y))
            tol.append(p.max_residual + math.sqrt((x - sc.ox) * (x - sc.ox) + (y - sc.oy) * (y - sc.oy)) *
                       abs(sc.rays.increment))
        lx, ly = pts[-1][1], pts[-1][2]
        reach = 0.0  # the furthest the end was from where it is: no run can travel more (but the residuals)
        for _, x, y in pts:
            reach = max(reach, math.sqrt((x - lx) * (x - lx) + (y - ly) * (y - ly)))
        if reach + 2.0 * max(tol) < p.end_travel:
            return None
        for i in range(len(pts) - p.min_obs + 1):
            v = _fit(pts[i:], p, tol[i:])
            if v is None:
                continue
            speed = math.sqrt(v[0] * v[0] + v[1] * v[1])
            if (p.min_speed <= speed <= p.max_speed and speed * (pts[-1][0] - pts[i][0]) >= p.end_travel and
                    self._moved_through(k, i)):
                return v
            return None
        return None

    def _predict(self, xy, a, b, ux, uy, speed, out_xy, out_v) -> None:
        """The cluster's points a..b-1 (at most max_points, evenly picked) moved by (ux, uy)
        [m/s, base_link] for 1..J steps over the horizon (standing: J = 0, the points as they
        are), each with its four copies ``clearance`` away. Appends arrays (points x 2, and
        their speeds) to ``out_xy`` and ``out_v``: step by step, point by point, a point
        before its copies (the order and the arithmetic of the C++ guard's loops)."""
        p = self.p
        idx = picks(a, b, p.max_points)
        steps = max(1, int(math.ceil(speed * p.horizon / p.step))) if speed > 0.0 else 0
        cl = p.clearance

        def points(x, y, itself: bool) -> np.ndarray:  # x, y: (..., k) -> (..., k, point and copies, 2)
            cols = ([(x, y)] if itself else []) + ([(x + cl, y), (x - cl, y), (x, y + cl), (x, y - cl)]
                                                   if cl > 0.0 else [])
            if not cols:
                return np.zeros((0, 2))
            return np.stack([np.stack((cx, cy), axis=-1) for cx, cy in cols], axis=-2).reshape(-1, 2)

        px, py = xy[idx, 0].astype(float), xy[idx, 1].astype(float)
        blocks = [points(px + ux * 0.0, py + uy * 0.0, False)]  # j = 0: where it is now (the scan holds the point)
        if steps:
            tau = np.array([p.horizon * j / steps for j in range(1, steps + 1)])[:, None]
            blocks.append(points(px[None, :] + ux * tau, py[None, :] + uy * tau, True))
        pts = np.concatenate(blocks)
        if len(pts):
            out_xy.append(pts)
            out_v.append(np.full(len(pts), float(speed)))
