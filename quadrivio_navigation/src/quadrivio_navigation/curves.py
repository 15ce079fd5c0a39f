"""Shortest paths of a car with a minimum turning radius, without obstacles.

* **Reeds-Shepp** (forwards and backwards): the shortest of the 48 path words of
  J. A. Reeds and L. A. Shepp, "Optimal paths for a car that goes both forwards and
  backwards", Pacific J. Math. 145(2), 1990, formulas 8.1-8.11 (with the corrections
  OMPL's ReedsSheppStateSpace makes to 8.3/8.4 and 8.11);
* **Dubins** (forwards only): the shortest of the six words LSL, RSR, LSR, RSL, RLR, LRL.

A path is a list of segments ``(kind, length)``: kind ``L`` (left arc), ``R`` (right
arc) or ``S`` (straight), length in metres, negative when driven backwards. All
computations are in units of the turning radius ``r`` internally. The goal, expressed
in the start's frame, is ``(x, y, phi)``::

    x = cos(th0) dx + sin(th0) dy,  y = -sin(th0) dx + cos(th0) dy,  phi = th1 - th0

:func:`rs_length_batch` and :func:`dubins_length_batch` give lengths for arrays of goals
(numpy, for heuristic tables). ROS-free.
"""

from __future__ import annotations

import math
from typing import List, Optional, Sequence, Tuple

import numpy as np

PI = math.pi
TWO_PI = 2.0 * math.pi
ZERO = 1e-9

Segment = Tuple[str, float]


def wrap_angles(a: np.ndarray) -> np.ndarray:
    """Angles wrapped to [-pi, pi) by exact arithmetic: ``arctan2(sin, cos)`` runs through
    numpy's SIMD kernels, whose last bit depends on the array's memory alignment, and a
    plan must come out the same every time."""
    return np.mod(np.asarray(a, dtype=float) + PI, TWO_PI) - PI


def mod2pi(x: float) -> float:
    """Angle wrapped to (-pi, pi]."""
    v = math.fmod(x, TWO_PI)
    if v < -PI:
        v += TWO_PI
    elif v > PI:
        v -= TWO_PI
    return v


def _polar(x: float, y: float) -> Tuple[float, float]:
    return math.hypot(x, y), math.atan2(y, x)


def _tau_omega(u: float, v: float, xi: float, eta: float, phi: float) -> Tuple[float, float]:
    delta = mod2pi(u - v)
    a = math.sin(u) - math.sin(delta)
    b = math.cos(u) - math.cos(delta) - 1.0
    t1 = math.atan2(eta * a - xi * b, xi * a + eta * b)
    t2 = 2.0 * (math.cos(delta) - math.cos(v) - math.cos(u)) + 3.0
    tau = mod2pi(t1 + PI) if t2 < 0 else mod2pi(t1)
    return tau, mod2pi(tau - u + v - phi)


# ---- the base formulas (one word each; the others follow by time-flip and reflection)
def _lsl(x, y, phi):  # 8.1  L+ S+ L+
    u, t = _polar(x - math.sin(phi), y - 1.0 + math.cos(phi))
    if t >= -ZERO:
        v = mod2pi(phi - t)
        if v >= -ZERO:
            return t, u, v
    return None


def _lsr(x, y, phi):  # 8.2  L+ S+ R+
    u1, t1 = _polar(x + math.sin(phi), y - 1.0 - math.cos(phi))
    u1 = u1 * u1
    if u1 >= 4.0:
        u = math.sqrt(u1 - 4.0)
        t = mod2pi(t1 + math.atan2(2.0, u))
        v = mod2pi(t - phi)
        if t >= -ZERO and v >= -ZERO:
            return t, u, v
    return None


def _lrl(x, y, phi):  # 8.3 L+ R- L+
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    u1, theta = _polar(xi, eta)
    if u1 <= 4.0:
        u = -2.0 * math.asin(0.25 * u1)
        t = mod2pi(theta + 0.5 * u + PI)
        v = mod2pi(phi - t + u)
        if t >= -ZERO and u <= ZERO:
            return t, u, v
    return None


def _lrlr_a(x, y, phi):  # 8.7  L+ R+ L- R-
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = 0.25 * (2.0 + math.hypot(xi, eta))
    if rho <= 1.0:
        u = math.acos(rho)
        t, v = _tau_omega(u, -u, xi, eta, phi)
        if t >= -ZERO and v <= ZERO:
            return t, u, v
    return None


def _lrlr_b(x, y, phi):  # 8.8  L+ R- L- R+
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho = (20.0 - xi * xi - eta * eta) / 16.0
    if 0.0 <= rho <= 1.0:
        u = -math.acos(rho)
        if u >= -0.5 * PI:
            t, v = _tau_omega(u, u, xi, eta, phi)
            if t >= -ZERO and v >= -ZERO:
                return t, u, v
    return None


def _lrsl(x, y, phi):  # 8.9  L+ R- S- L-
    xi, eta = x - math.sin(phi), y - 1.0 + math.cos(phi)
    rho, theta = _polar(xi, eta)
    if rho >= 2.0:
        r = math.sqrt(rho * rho - 4.0)
        u = 2.0 - r
        t = mod2pi(theta + math.atan2(r, -2.0))
        v = mod2pi(phi - 0.5 * PI - t)
        if t >= -ZERO and u <= ZERO and v <= ZERO:
            return t, u, v
    return None


def _lrsr(x, y, phi):  # 8.10 L+ R- S- R-
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho, theta = _polar(-eta, xi)
    if rho >= 2.0:
        t = theta
        u = 2.0 - rho
        v = mod2pi(t + 0.5 * PI - phi)
        if t >= -ZERO and u <= ZERO and v <= ZERO:
            return t, u, v
    return None


def _lrslr(x, y, phi):  # 8.11 L+ R- S- L- R+
    xi, eta = x + math.sin(phi), y - 1.0 - math.cos(phi)
    rho, _ = _polar(xi, eta)
    if rho >= 2.0:
        u = 4.0 - math.sqrt(rho * rho - 4.0)
        if u <= ZERO:
            t = mod2pi(math.atan2((4.0 - u) * xi - 2.0 * eta, -2.0 * xi + (u - 4.0) * eta))
            v = mod2pi(t - phi)
            if t >= -ZERO and v >= -ZERO:
                return t, u, v
    return None


_SWAP = {"L": "R", "R": "L", "S": "S"}
H = 0.5 * PI


def _candidates(x: float, y: float, phi: float):
    """Every admissible word as (letters, signed lengths) in units of r."""
    out = []
    # the time-flipped, reflected and both variants of each formula (x, y, phi signs, flip, reflect)
    variants = ((1, 1, 1, 1, False), (-1, 1, -1, -1, False), (1, -1, -1, 1, True), (-1, -1, 1, -1, True))

    def family(fn, letters, make, x_, y_):
        for sx, sy, sphi, flip, refl in variants:
            r = fn(sx * x_, sy * y_, sphi * phi)
            if r is not None:
                lens = [flip * v for v in make(*r)]
                word = "".join(_SWAP[c] for c in letters) if refl else letters
                out.append((word, lens))

    xb = x * math.cos(phi) + y * math.sin(phi)  # the goal seen from the end, for the backward words
    yb = x * math.sin(phi) - y * math.cos(phi)

    def four(fn, letters, make):
        family(fn, letters, make, x, y)

    def four_back(fn, letters, make):
        family(fn, letters, make, xb, yb)

    four(_lsl, "LSL", lambda t, u, v: (t, u, v))
    four(_lsr, "LSR", lambda t, u, v: (t, u, v))
    four(_lrl, "LRL", lambda t, u, v: (t, u, v))
    four_back(_lrl, "LRL", lambda t, u, v: (v, u, t))
    four(_lrlr_a, "LRLR", lambda t, u, v: (t, u, -u, v))
    four(_lrlr_b, "LRLR", lambda t, u, v: (t, u, u, v))
    four(_lrsl, "LRSL", lambda t, u, v: (t, -H, u, v))
    four(_lrsr, "LRSR", lambda t, u, v: (t, -H, u, v))
    four_back(_lrsl, "LSRL", lambda t, u, v: (v, u, -H, t))
    four_back(_lrsr, "RSRL", lambda t, u, v: (v, u, -H, t))
    four(_lrslr, "LRSLR", lambda t, u, v: (t, -H, u, -H, v))
    return out


def _relative(start: Sequence[float], goal: Sequence[float], r: float) -> Tuple[float, float, float]:
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    c, s = math.cos(start[2]), math.sin(start[2])
    return (c * dx + s * dy) / r, (-s * dx + c * dy) / r, goal[2] - start[2]


def reeds_shepp(start: Sequence[float], goal: Sequence[float], r: float, reverse_cost: float = 1.0) -> List[Segment]:
    """The shortest Reeds-Shepp path from ``start`` to ``goal`` (poses x, y, theta) for
    turning radius ``r``: segments (kind, signed length in m). With ``reverse_cost`` > 1
    the word whose length, reverse parts counted that many times, is least."""
    x, y, phi = _relative(start, goal, r)
    best, best_len = None, math.inf
    for word, lens in _candidates(x, y, phi):
        L = sum(abs(v) if v > 0 else -reverse_cost * v for v in lens)
        if L < best_len - 1e-12:
            best, best_len = (word, lens), L
    if best is None:  # cannot happen: some word always exists
        raise ArithmeticError(f"no Reeds-Shepp path for {(x, y, phi)}")
    return [(k, v * r) for k, v in zip(best[0], best[1]) if abs(v) > 1e-12]


# ----------------------------------------------------------------------- Dubins
def _m(x: float) -> float:
    """Angle wrapped to [0, 2 pi)."""
    return x - TWO_PI * math.floor(x / TWO_PI)


def dubins(start: Sequence[float], goal: Sequence[float], r: float) -> List[Segment]:
    """The shortest forward-only (Dubins) path from ``start`` to ``goal``."""
    dx, dy = goal[0] - start[0], goal[1] - start[1]
    d = math.hypot(dx, dy) / r
    th = math.atan2(dy, dx) if d > 1e-12 else 0.0
    a, b = _m(start[2] - th), _m(goal[2] - th)
    sa, sb, ca, cb = math.sin(a), math.sin(b), math.cos(a), math.cos(b)
    cab = math.cos(a - b)
    words = []
    tmp = 2 + d * d - 2 * cab + 2 * d * (sa - sb)
    if tmp >= -1e-7:  # OMPL's DUBINS_ZERO: a straight of length 0 is a word too
        theta = math.atan2(cb - ca, d + sa - sb)
        words.append(("LSL", (_m(theta - a), math.sqrt(max(tmp, 0.0)), _m(b - theta))))
    tmp = 2 + d * d - 2 * cab + 2 * d * (sb - sa)
    if tmp >= -1e-7:
        theta = math.atan2(ca - cb, d - sa + sb)
        words.append(("RSR", (_m(a - theta), math.sqrt(max(tmp, 0.0)), _m(theta - b))))
    tmp = d * d - 2 + 2 * cab - 2 * d * (sa + sb)
    if tmp >= -1e-7:
        p = math.sqrt(max(tmp, 0.0))
        theta = math.atan2(ca + cb, d - sa - sb) - math.atan2(2.0, p)
        words.append(("RSL", (_m(a - theta), p, _m(b - theta))))
    tmp = -2 + d * d + 2 * cab + 2 * d * (sa + sb)
    if tmp >= -1e-7:
        p = math.sqrt(max(tmp, 0.0))
        theta = math.atan2(-ca - cb, d + sa + sb) - math.atan2(-2.0, p)
        words.append(("LSR", (_m(theta - a), p, _m(theta - b))))
    tmp = (6.0 - d * d + 2 * cab + 2 * d * (sa - sb)) / 8.0
    if abs(tmp) <= 1.0:
        p = _m(TWO_PI - math.acos(tmp))
        theta = math.atan2(ca - cb, d - sa + sb)
        t = _m(a - theta + 0.5 * p)
        words.append(("RLR", (t, p, _m(a - b - t + p))))
    tmp = (6.0 - d * d + 2 * cab + 2 * d * (sb - sa)) / 8.0
    if abs(tmp) <= 1.0:
        p = _m(TWO_PI - math.acos(tmp))
        theta = math.atan2(ca - cb, d + sa - sb)
        t = _m(-a - theta + 0.5 * p)
        words.append(("LRL", (t, p, _m(b - a - t + p))))
    word, lens = min(words, key=lambda w: sum(w[1]))
    return [(k, v * r) for k, v in zip(word, lens) if abs(v) > 1e-12]


def shortest_path(start: Sequence[float], goal: Sequence[float], r: float, reverse: bool,
                  reverse_cost: float = 1.0) -> List[Segment]:
    """Reeds-Shepp when reversing is allowed, else Dubins."""
    return reeds_shepp(start, goal, r, reverse_cost) if reverse else dubins(start, goal, r)


def path_length(segments: Sequence[Segment]) -> float:
    return float(sum(abs(v) for _, v in segments))


def path_cost(segments: Sequence[Segment], reverse_cost: float = 1.0) -> float:
    """Length with the reverse parts counted ``reverse_cost`` times [m]."""
    return float(sum(v if v > 0 else -reverse_cost * v for _, v in segments))


def rs_cost(x: float, y: float, phi: float, r: float, reverse_cost: float = 1.0) -> float:
    """Cost (:func:`path_cost`) of the cheapest Reeds-Shepp word to the goal (x, y, phi)
    given in the start's frame [m, m, rad]."""
    best = math.inf
    for _, lens in _candidates(x / r, y / r, phi):
        c = sum(v if v > 0 else -reverse_cost * v for v in lens)
        if c < best:
            best = c
    return best * r


def advance(x: float, y: float, th: float, kind: str, length: float, r: float) -> Tuple[float, float, float]:
    """The pose after driving ``length`` m (negative: backwards) on a segment of ``kind``."""
    if kind == "S":
        return x + length * math.cos(th), y + length * math.sin(th), th
    phi = length / r if kind == "L" else -length / r
    sign = 1.0 if kind == "L" else -1.0
    return (x + sign * r * (math.sin(th + phi) - math.sin(th)), y - sign * r * (math.cos(th + phi) - math.cos(th)),
            th + phi)


def sample(start: Sequence[float], segments: Sequence[Segment], r: float, step: float) -> Tuple[np.ndarray, np.ndarray]:
    """Poses (N x 3) every ``step`` m along a path, both ends included, and the driving
    direction (+1 / -1) of the motion from each pose to the next (the last repeats)."""
    poses = [tuple(start)]
    dirs: List[int] = []
    x, y, th = start
    for kind, length in segments:
        n = max(1, int(math.ceil(abs(length) / step)))
        for i in range(1, n + 1):
            poses.append(advance(x, y, th, kind, length * i / n, r))
            dirs.append(1 if length > 0 else -1)
        x, y, th = poses[-1]
    dirs.append(dirs[-1] if dirs else 1)
    return np.array(poses, dtype=float), np.array(dirs, dtype=np.int8)


def end_pose(start: Sequence[float], segments: Sequence[Segment], r: float) -> Tuple[float, float, float]:
    x, y, th = start
    for kind, length in segments:
        x, y, th = advance(x, y, th, kind, length, r)
    return x, y, th


# --------------------------------------------------------------- batch lengths
def rs_length_batch(x: np.ndarray, y: np.ndarray, phi: np.ndarray, r: float) -> np.ndarray:
    """Reeds-Shepp lengths [m] for arrays of goals in the start's frame (x, y in m)."""
    return _batch(np.asarray(x, float) / r, np.asarray(y, float) / r, np.asarray(phi, float), True) * r


def dubins_length_batch(x: np.ndarray, y: np.ndarray, phi: np.ndarray, r: float) -> np.ndarray:
    """Dubins lengths [m] for arrays of goals in the start's frame."""
    return _batch(np.asarray(x, float) / r, np.asarray(y, float) / r, np.asarray(phi, float), False) * r


def _batch(x: np.ndarray, y: np.ndarray, phi: np.ndarray, reverse: bool) -> np.ndarray:
    # The scalar functions run per element; fast enough for tables of a few 10^5
    # entries built once per planner (about 20 us each).
    out = np.empty(x.shape, dtype=float)
    fx, fy, fp, fo = x.ravel(), y.ravel(), phi.ravel(), out.reshape(-1)
    for i in range(fx.size):
        if reverse:
            fo[i] = min(sum(abs(v) for v in lens) for _, lens in _candidates(fx[i], fy[i], fp[i]))
        else:
            fo[i] = path_length(dubins((0.0, 0.0, 0.0), (fx[i], fy[i], fp[i]), 1.0))
    return out


def relative_goal(start: Sequence[float], goal: Sequence[float]) -> Tuple[float, float, float]:
    """The goal in the start's frame, in metres and radians."""
    x, y, phi = _relative(start, goal, 1.0)
    return x, y, phi


def turning_angle(segments: Sequence[Segment], r: float) -> float:
    """Total absolute heading change along a path [rad]."""
    return float(sum(abs(v) / r for k, v in segments if k != "S"))


def check_curvature(poses: np.ndarray, r: float, tol: float = 1e-6) -> Optional[float]:
    """The largest curvature |dtheta / ds| along sampled poses if it exceeds 1/r, else None."""
    d = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    dth = np.abs(np.diff(np.unwrap(poses[:, 2])))
    moving = d > 1e-9
    if not moving.any():
        return None
    k = float(np.max(dth[moving] / d[moving]))
    return k if k > 1.0 / r + tol else None
