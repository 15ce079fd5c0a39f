"""Reference paths: the paper's figure eight, straight lines, polylines; path geometry.

A :class:`Path` is a sequence of poses sampled every ``ds`` metres with heading,
curvature, arc length and a speed profile. The figure eight (paper section 4) starts
``lead`` metres ahead of the vehicle: from there a circle of diameter ``d1`` on the
left, then one of diameter ``d2`` on the right, both tangent to the vehicle's heading
at the crossing point, repeated ``laps`` times.

Speed profile: ``v(s) = min(v_max, sqrt(a_lat / |kappa(s)|))``, then limited so that
decelerating at ``a_dec`` reaches 0 at the end (and accelerating at ``a_acc`` from 0 at
the start): ``v(s) <= sqrt(2 a (L - s))``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import param


@dataclass(frozen=True)
class FigureEightParams:
    diameter_first: float = param(18.0, lo=1.0, hi=1000.0, unit="m", doc="first (left) circle")
    diameter_second: float = param(12.5, lo=1.0, hi=1000.0, unit="m", doc="second (right) circle")
    lead: float = param(1.0, lo=0.0, hi=100.0, unit="m", doc="crossing point ahead of the vehicle's start pose")
    laps: int = param(1, lo=1, hi=100, doc="times the eight is driven")


@dataclass(frozen=True)
class SpeedProfileParams:
    speed: float = param(2.0, lo=0.1, hi=20.0, unit="m/s", doc="target speed")
    max_lateral_accel: float = param(1.5, lo=0.1, hi=10.0, unit="m/s^2", doc="curvature speed limit")
    accel: float = param(1.0, lo=0.05, hi=10.0, unit="m/s^2", doc="speed-up limit of the profile")
    decel: float = param(1.0, lo=0.05, hi=10.0, unit="m/s^2", doc="slow-down limit of the profile (to the end)")


@dataclass(frozen=True)
class PathParams:
    kind: str = param("figure_eight", choices=("figure_eight", "waypoints", "goal"),
                      doc="a reference path, or a goal the planner plans to")
    figure_eight: FigureEightParams = param(FigureEightParams())
    waypoints: Tuple[Tuple[float, float], ...] = param((), unit="m", doc="in the vehicle's start frame (x ahead)")
    goal: Tuple[float, float, float] = param((0.0, 0.0, 0.0), lo=-1e6, hi=1e6, unit="m, m, rad",
                                             doc="kind goal: the goal pose in the map frame")
    ds: float = param(0.1, lo=0.01, hi=5.0, unit="m", doc="spacing of the published poses")
    frame_id: str = param("map")


@dataclass
class Path:
    x: np.ndarray  # [m] map frame
    y: np.ndarray
    theta: np.ndarray  # [rad] heading
    kappa: np.ndarray  # [1/m] curvature
    s: np.ndarray  # [m] arc length
    v: np.ndarray  # [m/s] speed profile

    def __len__(self) -> int:
        return len(self.x)

    @property
    def length(self) -> float:
        return float(self.s[-1])

    def xy(self) -> np.ndarray:
        return np.column_stack([self.x, self.y])


def arc_points(cx: float, cy: float, r: float, start_angle: float, sweep: float, ds: float) -> np.ndarray:
    """Points on a circle of centre (cx, cy), radius r, from ``start_angle`` sweeping ``sweep`` rad."""
    n = max(2, int(math.ceil(abs(sweep) * r / ds)) + 1)
    a = start_angle + np.linspace(0.0, sweep, n)
    return np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a)])


def figure_eight(p: FigureEightParams, start: Tuple[float, float, float] = (0.0, 0.0, 0.0),
                 ds: float = 0.1) -> np.ndarray:
    """The eight's points (N x 2) in the map frame for a vehicle starting at ``start``."""
    x0, y0, th = start
    c, s = math.cos(th), math.sin(th)
    px, py = x0 + p.lead * c, y0 + p.lead * s  # crossing point
    r1, r2 = 0.5 * p.diameter_first, 0.5 * p.diameter_second
    # Left circle: centre r1 to the left of the crossing, counter-clockwise from the crossing.
    c1 = (px - r1 * s, py + r1 * c)
    # Right circle: centre r2 to the right, clockwise.
    c2 = (px + r2 * s, py - r2 * c)
    pieces = []
    for _ in range(p.laps):
        a1 = math.atan2(py - c1[1], px - c1[0])
        pieces.append(arc_points(*c1, r1, a1, 2.0 * math.pi, ds))
        a2 = math.atan2(py - c2[1], px - c2[0])
        pieces.append(arc_points(*c2, r2, a2, -2.0 * math.pi, ds))
    pts = np.vstack([pieces[0]] + [q[1:] for q in pieces[1:]])
    return pts


def resample(points: np.ndarray, ds: float) -> np.ndarray:
    """Points of a polyline at equal arc-length spacing ``ds``."""
    d = np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1]))
    keep = np.concatenate([[True], d > 1e-9])
    points = points[keep]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(points[:, 0]), np.diff(points[:, 1])))])
    if s[-1] < ds:
        return points
    grid = np.linspace(0.0, s[-1], int(round(s[-1] / ds)) + 1)
    return np.column_stack([np.interp(grid, s, points[:, 0]), np.interp(grid, s, points[:, 1])])


def make_path(points: np.ndarray, profile: SpeedProfileParams, ds: float = 0.1, v_start: float = 0.0,
              v_max: Optional[float] = None) -> Path:
    """A :class:`Path` (heading of the motion, curvature, arc length, speed profile)
    through ``points``; the profile starts from ``v_start`` [m/s] (a vehicle already
    moving) and never exceeds ``v_max`` (default the profile's speed)."""
    pts = resample(np.asarray(points, float), ds)
    if len(pts) < 2 or (len(pts) == 2 and math.hypot(*(pts[1] - pts[0])) < 1e-9):
        raise ValueError("a path needs at least 2 distinct points")
    if len(pts) == 2:  # a short straight: sample it so that the geometry below works
        pts = np.column_stack([np.linspace(pts[0, 0], pts[1, 0], 3), np.linspace(pts[0, 1], pts[1, 1], 3)])
    dx, dy = np.gradient(pts[:, 0]), np.gradient(pts[:, 1])
    theta = np.unwrap(np.arctan2(dy, dx))
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1])))])
    kappa = np.gradient(theta, s)
    v = speed_profile(s, kappa, profile, v_start, v_max)
    return Path(pts[:, 0], pts[:, 1], np.arctan2(np.sin(theta), np.cos(theta)), kappa, s, v)


def speed_profile(s: np.ndarray, kappa: np.ndarray, p: SpeedProfileParams, v_start: float = 0.0,
                  v_max: Optional[float] = None) -> np.ndarray:
    """See the module docstring; the acceleration limit applies from ``v_start``."""
    top = p.speed if v_max is None else min(p.speed, v_max)
    with np.errstate(divide="ignore"):
        v = np.minimum(top, np.sqrt(p.max_lateral_accel / np.maximum(np.abs(kappa), 1e-9)))
    # smooth the curvature limit both ways with the acceleration limits
    v[0] = min(v[0], max(v_start, 0.0))
    for i in range(1, len(s)):
        v[i] = min(v[i], math.sqrt(v[i - 1] ** 2 + 2 * p.accel * (s[i] - s[i - 1])))
    v[-1] = 0.0
    for i in range(len(s) - 2, -1, -1):
        v[i] = min(v[i], math.sqrt(v[i + 1] ** 2 + 2 * p.decel * (s[i + 1] - s[i])))
    v[0] = max(v[0], min(top, 0.3))  # start moving
    return v


class Tracker:
    """Progress along a path that may cross itself: the nearest point is searched only
    in a window ahead of (and a little behind) the last one."""

    def __init__(self, path: Path, window: float = 5.0) -> None:
        self.path = path
        self.i = 0
        self.window = max(2, int(window / max(1e-6, path.s[1] - path.s[0])))

    def nearest(self, x: float, y: float) -> int:
        lo = max(0, self.i - self.window // 4)
        hi = min(len(self.path), self.i + self.window)
        d2 = (self.path.x[lo:hi] - x) ** 2 + (self.path.y[lo:hi] - y) ** 2
        self.i = lo + int(np.argmin(d2))
        return self.i

    def cross_track(self, x: float, y: float, i: Optional[int] = None) -> float:
        """Signed distance to the path at its point ``i`` (left positive)."""
        i = self.nearest(x, y) if i is None else i
        p = self.path
        return float(-math.sin(p.theta[i]) * (x - p.x[i]) + math.cos(p.theta[i]) * (y - p.y[i]))


def distance_to_polyline(points: np.ndarray, x: float, y: float) -> float:
    """Shortest distance from (x, y) to a polyline (segment-exact)."""
    a, b = points[:-1], points[1:]
    ab = b - a
    t = ((x - a[:, 0]) * ab[:, 0] + (y - a[:, 1]) * ab[:, 1]) / np.maximum((ab ** 2).sum(1), 1e-12)
    t = np.minimum(np.maximum(t, 0.0), 1.0)
    px, py = a[:, 0] + t * ab[:, 0], a[:, 1] + t * ab[:, 1]
    return float(np.sqrt(np.min((px - x) ** 2 + (py - y) ** 2)))


def polyline(points: Sequence[Sequence[float]]) -> np.ndarray:
    return np.asarray(points, dtype=float).reshape(-1, 2)


def path_points(kind: str, start: Tuple[float, float, float], figure: FigureEightParams,
                waypoints: Sequence[Sequence[float]] = (), ds: float = 0.1) -> np.ndarray:
    """Points of a reference path of ``kind``: figure_eight, or waypoints (a polyline from the start)."""
    if kind == "figure_eight":
        return figure_eight(figure, start, ds)
    if kind == "waypoints":
        if len(waypoints) < 1:
            raise ValueError("path kind 'waypoints' needs at least one waypoint")
        pts = np.vstack([[start[0], start[1]], polyline(waypoints)])
        return resample(pts, ds)
    raise ValueError(f"unknown path kind '{kind}' (figure_eight, waypoints)")
