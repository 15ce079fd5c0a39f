"""The local obstacle layer: laser scans marked and ray-cleared into a rolling grid.

The semantics are costmap_2d's obstacle layer, whose parameters robotics teams know:

* every return within ``obstacle_range`` of its scanner **marks** the cell it falls in;
* every ray **clears** the cells it crosses up to its return (or up to
  ``raytrace_range`` for a ray that saw nothing, +inf in REP 117), sampled every cell
  size, so an obstacle that has moved away is cleared by the rays that now pass through
  where it was;
* a mark not seen again for ``decay`` s is forgotten (0: never), so what left the
  scanners' view does not stay forever (costmap_2d's obstacle layer has no decay; its
  voxel-grid successors do);
* the grid rolls with the vehicle: ``size`` metres square centred on it, its origin
  snapped to whole cells so that marks stay put in the map frame.

Cells hold the time of their last mark (NaN: never marked or cleared since). The grid
as a nav_msgs/OccupancyGrid: 100 marked, 0 seen free, -1 unknown.

**Ground returns.** A planar scanner mounted level sees the ground only where the ground
rises into its plane ahead (a bank, the far side of a dip) or when the vehicle pitches
into it. Where the terrain's height ``z(x, y)`` is known (a DEM: the scenario's terrain,
a survey), a return whose height, from the scanner's 3D pose (the vehicle's roll and
pitch, REP-103, standing on its wheels on the terrain), lies within ``ground_tolerance``
(grown by the pose's uncertainty, :func:`terrain_ground`) of the terrain is the ground: it
neither marks nor clears beyond itself. Without a DEM nothing is taken for the ground:
the vehicle's pitch alone cannot tell a bank from the obstacle at the foot of a slope it
drives down (its scan plane is parallel to that slope), and what cannot be told apart
stops the vehicle.

Pure and ROS-free: points and poses in, a grid out.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Optional, Tuple

import numpy as np

from quadrivio_config import param

from .guard import ScannerParams


@dataclass(frozen=True)
class LocalLayerParams:
    size: float = param(24.0, lo=2.0, hi=500.0, unit="m", doc="side of the rolling square grid")
    resolution: float = param(0.1, lo=0.02, hi=2.0, unit="m", doc="cell size")
    obstacle_range: float = param(10.0, lo=0.1, hi=100.0, unit="m", doc="returns further away mark nothing")
    raytrace_range: float = param(10.0, lo=0.1, hi=100.0, unit="m", doc="rays clear up to here at most")
    decay: float = param(15.0, lo=0.0, hi=600.0, unit="s", doc="a mark not seen again this long is forgotten (0: never)")
    ground_tolerance: float = param(0.15, lo=0.0, hi=2.0, unit="m",
                                    doc="a return within this of the ground (DEM) or of where the scan plane meets "
                                        "level ground is the ground")
    ground_tolerance_per_m: float = param(0.02, lo=0.0, hi=0.2, unit="m/m",
                                          doc="...plus this per metre of range: the attitude's error (0.02: 1.1 deg) "
                                              "at the range where a braking vehicle's scan plane meets the ground")
    ground_position_sigmas: float = param(
        2.0, lo=0.0, hi=10.0, doc="...plus the DEM's gradient under the return times this many of the pose's "
                                  "horizontal sds (the terrain under a return drawn from a pose that is off)")
    ground_tolerance_max: float = param(
        0.3, lo=0.0, hi=2.0, unit="m", doc="the ground tolerance never exceeds this: keep it under the scan plane's "
                                           "height over the ground (0.57 m for the front laser)")


_TRACE = None  # qv_layer_trace of libquadrivio_guard.so, once found; False: not there


def native_trace():
    """The native ray tracing (``src/layer_capi.cpp``, in the guard's library), or None where
    the workspace is not built: :meth:`LocalLayer.add_scan` then traces in numpy, the reference."""
    global _TRACE
    if _TRACE is None:
        import ctypes

        from .guard_native import GuardUnavailable, load_library
        try:
            fn = load_library().qv_layer_trace
        except (GuardUnavailable, AttributeError):  # not built, or built before the layer was in it
            _TRACE = False
        else:
            d, lg, ptr = ctypes.c_double, ctypes.c_long, ctypes.c_void_p
            fn.restype = None
            fn.argtypes = [ptr, ptr, lg, d, d, d, d, d, lg, ptr, ptr, ptr, ptr, ptr, d]
            _TRACE = fn
    return _TRACE or None


class LocalLayer:
    """``native``: trace the rays in native code (the same cells; a 271-ray scan 0.2 ms against
    numpy's 0.9-1.0, which was a sixth of a closed-loop orchard run); None: where the library
    is built."""

    def __init__(self, p: LocalLayerParams, native: Optional[bool] = None) -> None:
        self.p = p
        self._trace = native_trace() if native is not False else None
        if native and self._trace is None:
            raise RuntimeError("the local layer's native tracing: libquadrivio_guard.so with qv_layer_trace not "
                               "found (build the workspace: make setup)")
        self.n = int(round(p.size / p.resolution))
        self.stamp = np.full((self.n, self.n), np.nan)  # [s] last mark; NaN: not marked
        self.seen = np.zeros((self.n, self.n), dtype=bool)  # seen free (cleared) at least once
        self.origin = (0.0, 0.0)  # map coordinates of cell (0, 0)'s corner
        self.placed = False
        self.ground_returns = 0
        self.t = -math.inf  # the newest scan's time

    # ------------------------------------------------------------- geometry
    def recentre(self, x: float, y: float) -> None:
        """Roll the grid so that (x, y) is at its centre (whole cells: marks stay put)."""
        r = self.p.resolution
        ox = math.floor((x - 0.5 * self.p.size) / r) * r
        oy = math.floor((y - 0.5 * self.p.size) / r) * r
        if not self.placed:
            self.origin, self.placed = (ox, oy), True
            return
        dx = int(round((ox - self.origin[0]) / r))
        dy = int(round((oy - self.origin[1]) / r))
        if dx == 0 and dy == 0:
            return
        self.stamp = _shift(self.stamp, dx, dy, np.nan)
        self.seen = _shift(self.seen, dx, dy, False)
        self.origin = (self.origin[0] + dx * r, self.origin[1] + dy * r)

    def cells(self, xy: np.ndarray) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Rows, columns and an inside mask of map points (N x 2)."""
        r = self.p.resolution
        col = np.floor((xy[:, 0] - self.origin[0]) / r).astype(int)
        row = np.floor((xy[:, 1] - self.origin[1]) / r).astype(int)
        ok = (row >= 0) & (col >= 0) & (row < self.n) & (col < self.n)
        return row, col, ok

    # --------------------------------------------------------------- update
    def add_scan(self, t: float, sensor: Tuple[float, float, float], bearings: np.ndarray, ranges: np.ndarray,
                 ground: Optional[Callable[[np.ndarray, np.ndarray], np.ndarray]] = None) -> None:
        """One scan: the scanner at ``sensor`` = (x, y, heading) in the map [m, m, rad];
        ``bearings`` [rad] of its rays in its own frame and their ``ranges`` [m] (+inf:
        nothing; NaN: invalid, ignored; -inf: too close, at 0); ``ground(bearings, ranges)``
        (with a DEM, see :func:`dem_ground`) tells which returns are the ground."""
        p = self.p
        self.recentre(sensor[0], sensor[1])
        a = np.asarray(bearings, dtype=float)
        rr = np.asarray(ranges, dtype=float)
        valid = ~np.isnan(rr)
        a, rr = a[valid], rr[valid]
        nothing = np.isposinf(rr)
        rr = np.where(np.isneginf(rr), 0.0, rr)
        hit = ~nothing & (rr <= p.obstacle_range)
        world = a + sensor[2]
        ca, sa = np.cos(world), np.sin(world)
        end = np.where(nothing, p.raytrace_range, np.minimum(rr, p.raytrace_range))
        ex, ey = sensor[0] + end * ca, sensor[1] + end * sa
        if ground is not None and np.any(hit):
            g = np.zeros_like(hit)
            g[hit] = ground(a[hit], rr[hit])
            self.ground_returns += int(np.count_nonzero(g))
            hit &= ~g
        # clear along every ray, stopping one cell short of a return
        r = p.resolution
        steps = np.maximum(0, np.floor((end - (~nothing) * r) / r).astype(np.int64))
        if self._trace is not None:
            self._trace_native(t, sensor, ca, sa, end, steps, hit)
            self.t = max(self.t, t)
            return
        total = int(steps.sum())
        if total:
            ray = np.repeat(np.arange(len(end)), steps)
            first = np.cumsum(steps) - steps
            k = np.arange(total) - np.repeat(first, steps)
            d = (k + 0.5) * r
            px = sensor[0] + d * ca[ray]
            py = sensor[1] + d * sa[ray]
            row, col, ok = self.cells(np.column_stack([px, py]))
            row, col = row[ok], col[ok]
            self.stamp[row, col] = np.nan
            self.seen[row, col] = True
        if np.any(hit):
            row, col, ok = self.cells(np.column_stack([ex[hit], ey[hit]]))
            self.stamp[row[ok], col[ok]] = t
        self.t = max(self.t, t)

    def _trace_native(self, t: float, sensor, ca: np.ndarray, sa: np.ndarray, end: np.ndarray, steps: np.ndarray,
                      hit: np.ndarray) -> None:
        """The clearing and marking of :meth:`add_scan` in ``qv_layer_trace``, which writes the
        grids in place (C order: np.full and :func:`_shift` make them so). The rays' arrays
        are add_scan's own: new float64, int64 and bool arrays."""
        self._trace(self.stamp.ctypes.data, self.seen.ctypes.data, self.n, self.origin[0], self.origin[1],
                    self.p.resolution, float(sensor[0]), float(sensor[1]), len(end), ca.ctypes.data, sa.ctypes.data,
                    end.ctypes.data, steps.ctypes.data, hit.view(np.uint8).ctypes.data, float(t))

    def decay(self, now: Optional[float] = None) -> None:
        """Forget the marks not seen again for ``decay`` s (before reading the grid)."""
        now = self.t if now is None else now
        if self.p.decay > 0.0:
            with np.errstate(invalid="ignore"):
                self.stamp[self.stamp < now - self.p.decay] = np.nan

    def occupied(self) -> np.ndarray:
        """Boolean grid of marked cells (row = y, column = x), decayed marks left out."""
        self.decay()
        return ~np.isnan(self.stamp)

    def grid_values(self) -> np.ndarray:
        """int8 grid as nav_msgs/OccupancyGrid: 100 marked, 0 seen free, -1 unknown."""
        out = np.full((self.n, self.n), -1, dtype=np.int8)
        out[self.seen] = 0
        out[self.occupied()] = 100
        return out

    def marked_points(self) -> np.ndarray:
        """Map coordinates (N x 2) of the marked cells' centres."""
        rows, cols = np.nonzero(self.occupied())
        r = self.p.resolution
        return np.column_stack([self.origin[0] + (cols + 0.5) * r, self.origin[1] + (rows + 0.5) * r])


def _shift(a: np.ndarray, dx: int, dy: int, fill) -> np.ndarray:
    """``a`` moved by (-dy, -dx) cells (the grid's origin moved by (dx, dy)), new cells ``fill``."""
    out = np.full_like(a, fill)
    n_r, n_c = a.shape
    if abs(dx) >= n_c or abs(dy) >= n_r:
        return out
    src_r = slice(max(dy, 0), n_r + min(dy, 0))
    dst_r = slice(max(-dy, 0), n_r + min(-dy, 0))
    src_c = slice(max(dx, 0), n_c + min(dx, 0))
    dst_c = slice(max(-dx, 0), n_c + min(-dx, 0))
    out[dst_r, dst_c] = a[src_r, src_c]
    return out


def wheel_centres(vehicle) -> np.ndarray:
    """The four wheels' centres in base_link (x, y) [m]: front left, front right, rear left,
    rear right (base_link is the rear axle's centre, at the wheels' height at rest)."""
    wb, f, r = vehicle.wheelbase, 0.5 * vehicle.front_track, 0.5 * vehicle.rear_track
    return np.array([[wb, f], [wb, -f], [0.0, r], [0.0, -r]])


def base_on_wheels(heights: Callable[[np.ndarray, np.ndarray], np.ndarray], x: float, y: float,
                   R_map: np.ndarray, wheel_radius: float, wheels: np.ndarray) -> Tuple[float, float]:
    """base_link's height [m] of a vehicle at (x, y) with rotation ``R_map`` (roll, pitch,
    yaw) standing on the DEM on its wheels (``wheels``: their centres in base_link, (n, 2)):
    the mean over the wheels of the height at which each wheel's centre stands
    ``wheel_radius`` over the terrain under it. And the norm of the mean of the terrain's
    gradients under the wheels (central differences over ``GRADIENT_STEP``): how fast that
    height moves when the pose moves horizontally.

    The DEM's height under base_link alone is off by the bumps under the wheels: on the
    rough terrain at 3 m/s, 19 mm RMS (62 mm at worst) from the true pose against 5 mm
    (17 mm) from the wheels."""
    w = np.asarray(wheels, dtype=float)
    c = R_map[:, :2] @ w.T  # (3, n): the centres' offsets in the map
    px, py = x + c[0], y + c[1]
    z = float(np.mean(heights(px, py) + wheel_radius - c[2]))
    e = GRADIENT_STEP
    gx = float(np.mean(heights(px + e, py) - heights(px - e, py))) / (2.0 * e)
    gy = float(np.mean(heights(px, py + e) - heights(px, py - e))) / (2.0 * e)
    return z, math.hypot(gx, gy)


def scanner_pose_3d(heights: Callable[[np.ndarray, np.ndarray], np.ndarray], x: float, y: float, yaw: float,
                    roll: float, pitch: float, wheel_radius: float, t_b, R_b) -> Tuple[np.ndarray, np.ndarray]:
    """The scanner's 3D pose in the map (position (3,), rotation 3 x 3) from the vehicle's
    planar pose, its roll and pitch and its mount (``t_b`` (3,), ``R_b`` 3 x 3 in
    base_link): base_link stands ``wheel_radius`` above the DEM at (x, y) (on its wheels:
    :func:`terrain_ground` with ``wheels``)."""
    from quadrivio_description.frames import rpy_matrix

    R_map = np.array(rpy_matrix((roll, pitch, yaw)))
    z0 = float(heights(np.array([x]), np.array([y]))[0]) + wheel_radius
    return np.array([x, y, z0]) + R_map @ np.asarray(t_b, float), R_map @ np.asarray(R_b, float)


def scan_ground(ground: Callable[[np.ndarray, np.ndarray], np.ndarray], ranges, angle_min: float,
                angle_increment: float, range_min: float, range_max: float, max_range: float) -> np.ndarray:
    """Which of a scan's rays returned from the ground (:func:`dem_ground`): only returns
    inside the scanner's range (and ``max_range``) are tested."""
    r = np.asarray(ranges, dtype=float)
    bearings = angle_min + angle_increment * np.arange(len(r))
    hit = np.isfinite(r) & (r >= range_min) & (r <= min(range_max, max_range))
    out = np.zeros(len(r), dtype=bool)
    if hit.any():
        out[hit] = ground(bearings[hit], r[hit])
    return out


GRADIENT_STEP = 0.25  # [m] half the span of the DEM's central differences (dem_ground's slack)


def dem_ground(heights: Callable[[np.ndarray, np.ndarray], np.ndarray], position, rotation: np.ndarray,
               tolerance: float, per_metre: float = 0.0, slack: float = 0.0,
               cap: float = math.inf) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """A ``ground(bearings, ranges)`` test for :meth:`LocalLayer.add_scan` from a DEM
    ``heights(x, y)`` [m] and the scanner's 3D pose in the map (``position`` (3,),
    ``rotation`` 3 x 3): a return within ``tolerance + per_metre x range + slack x |grad h|``
    [m] of the terrain, at most ``cap``, is the ground.

    ``per_metre``: the tangent of the attitude's error, which moves a far return up or down
    by that much per metre of range. ``slack`` [m]: how far the pose may be off
    horizontally (a few of its standard deviations): the terrain under a return is then
    anywhere within that of where it is drawn, up to ``slack`` times the DEM's gradient
    there (central differences over ``GRADIENT_STEP``) off in height. ``cap`` keeps the
    tolerance below the scan plane's height over the ground, so that a person's legs stay
    an obstacle however uncertain the pose."""
    pos = np.asarray(position, dtype=float)

    def ground(bearings: np.ndarray, ranges: np.ndarray) -> np.ndarray:
        d = np.stack([np.cos(bearings), np.sin(bearings), np.zeros_like(bearings)])
        pts = pos[:, None] + rotation @ d * ranges
        tol = tolerance + per_metre * ranges
        if slack > 0.0:
            e = GRADIENT_STEP
            gx = (heights(pts[0] + e, pts[1]) - heights(pts[0] - e, pts[1])) / (2.0 * e)
            gy = (heights(pts[0], pts[1] + e) - heights(pts[0], pts[1] - e)) / (2.0 * e)
            tol = tol + slack * np.hypot(gx, gy)
        return np.abs(pts[2] - heights(pts[0], pts[1])) <= np.minimum(tol, cap)
    return ground


def terrain_ground(heights: Callable[[np.ndarray, np.ndarray], np.ndarray], pose, roll: float, pitch: float,
                   wheel_radius: float, t_b, R_b, tolerance: float, per_metre: float, sigmas: float,
                   cap: float, sd_min: float = 0.0,
                   wheels: Optional[np.ndarray] = None) -> Callable[[np.ndarray, np.ndarray], np.ndarray]:
    """The ground test (:func:`dem_ground`) of a scan from a scanner mounted at ``t_b``,
    ``R_b`` (base_link) on a vehicle at ``pose`` (x, y, yaw, horizontal sd of the position)
    with ``roll`` and ``pitch``: the slack is ``sigmas`` of that sd, taken as at least
    ``sd_min`` (the guard's ``ground_position_sd_min``: the estimate's own sd can be a third
    of its error on rough ground). With ``wheels`` (:func:`wheel_centres`) the vehicle
    stands on them (:func:`base_on_wheels`), and the scanner's own height is as uncertain as
    the returns': the slack times the gradient under the wheels joins the tolerance (on the
    rough terrain at 3 m/s a pose 0.36 m off put the front laser 0.13 m low on a bump's
    face, and the ground 3-4.6 m ahead read 0.16-0.22 m under the DEM: a false stop). The
    guard and the layer (their nodes and the one-process loop) all call this."""
    from quadrivio_description.frames import rpy_matrix

    x, y, yaw, sd = pose
    slack = sigmas * max(sd, sd_min)
    if wheels is None:
        pos, R = scanner_pose_3d(heights, x, y, yaw, roll, pitch, wheel_radius, t_b, R_b)
        return dem_ground(heights, pos, R, tolerance, per_metre, slack, cap)
    R_map = np.array(rpy_matrix((roll, pitch, yaw)))
    z0, grad = base_on_wheels(heights, x, y, R_map, wheel_radius, wheels)
    pos = np.array([x, y, z0]) + R_map @ np.asarray(t_b, float)
    return dem_ground(heights, pos, R_map @ np.asarray(R_b, float), tolerance + slack * grad, per_metre, slack, cap)


def scan_in_map(x: float, y: float, yaw: float, t_b, R_b, angle_min: float, angle_increment: float, ranges,
                range_min: float, range_max: float):
    """A scan for :meth:`LocalLayer.add_scan` from a vehicle at (x, y, yaw) (map): the
    scanner's planar pose (x, y, heading), the bearings (turned the other way for a scanner
    mounted upside down) and the ranges with returns outside [range_min, range_max] made
    NaN (REP 117's +-inf kept)."""
    c, sn = math.cos(yaw), math.sin(yaw)
    sensor = (x + c * t_b[0] - sn * t_b[1], y + sn * t_b[0] + c * t_b[1], yaw + math.atan2(R_b[1][0], R_b[0][0]))
    r = np.asarray(ranges, dtype=float)
    bearings = angle_min + angle_increment * np.arange(len(r))
    if R_b[2][2] < 0.0:  # mounted upside down: its angles turn the other way
        bearings = -bearings
    r = np.where(np.isfinite(r) & ((r < range_min) | (r > range_max)), np.nan, r)
    return sensor, bearings, r


@dataclass(frozen=True)
class LocalLayerNodeParams:
    """The layer node's own parameters (``config/local_layer.yaml``, beside :class:`LocalLayerParams`)."""
    scanners: Tuple[ScannerParams, ...] = param((), doc="the scanners to read; empty: the guard's (guard_ns)")
    guard_ns: str = param("/guard", doc="the guard node, whose scanners (with the scenario's guard: section) are "
                                        "read when scanners is empty")
    publish_rate: float = param(2.0, lo=0.1, hi=50.0, unit="Hz", doc="local_obstacles rate")
    frame_id: str = param("map")
    base_frame: str = param("base_link")
    terrain_from_scenario: bool = param(True, doc="returns on the scenario's known terrain are the ground")
    max_pose_age: float = param(0.5, lo=0.01, hi=10.0, unit="s", doc="a scan with no pose this fresh is dropped")
    only_with_goal: bool = param(True, doc="read the scans only while the planner pursues a goal (planner/status "
                                           "not IDLE): nothing else reads the layer")
