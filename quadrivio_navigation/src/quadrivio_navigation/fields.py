"""Protective and warning fields computed from the vehicle's motion, and laser points in them.

Industrial safety laser scanners switch their protective field with the speed (ISO 3691-4
for driverless trucks); nav2's collision monitor stops a robot whose projected motion
reaches a point within a time ("approach"). Here both are the same computation: the
footprint is swept along the path the vehicle will drive, and the distance along that
path before the swept footprint first touches a laser point is the *free distance*
``d_free``. A field of length ``d`` is violated when ``d_free < d``.

**The sweep.** From ``base_link`` (the rear axle centre, the footprint of
:class:`quadrivio_navigation.costmap.Footprint` around it), driving in direction
``dir`` (+1 forward, -1 reverse) a distance ``s`` with the handlebar moving from its
measured angle ``h_0`` toward the requested ``h_1`` at the servo's rate ``r``::

    h(s)       = h_0 + clip(h_1 - h_0, +-r s / v)
    kappa(s)   = tan(ratio h(s)) / L              (curvature of the rear axle's path)
    theta'(s)  = dir kappa(s),  x'(s) = dir cos theta,  y'(s) = dir sin theta

integrated in steps of ``ds``; a point ``p`` (base_link, metres) is in the footprint at
pose ``(x, y, theta)`` when ``R(-theta)(p - (x, y))`` lies in the rectangle.

**Stopping distance** at speed ``v`` [m/s] on a slope ``phi`` [rad, positive downhill in
the direction of travel], with ``t_r`` the time from the scan to the brakes acting (the
scan's age, the link, the brake servo's dead time and rise) and ``a`` the braking
deceleration on level ground::

    a_eff   = max(a - g sin(phi), a_min)
    d_stop  = v t_r + v^2 / (2 a_eff)

The protective field is ``d_stop(v) + margin`` at the measured speed with the brake's
deceleration; the warning field is the same at a gentle deceleration ``a_slow`` (the
speed loop's own ramp, below it) with the next scan's period added to ``t_r`` and a
larger margin. The speed it allows is the inverse (the positive root)::

    v_allow(d) = a (-t_r + sqrt(t_r^2 + 2 (d - margin) / a))     (0 when d <= margin)

so that a vehicle slowed down to ``v_allow(d_free)`` stays out of its protective field.

**Laser ranges** follow REP 117: NaN is an invalid reading, +inf means nothing within
``range_max``, -inf an object closer than ``range_min`` (taken at ``range_min`` along its
ray); a finite range outside ``[range_min, range_max]`` is invalid. Drivers older than REP
117 report a ray that saw nothing otherwise: 0.0 (LMS1xx without
``publish_min_range_as_inf``, older sick_tim, an Ouster's scan) or a range beyond
``range_max`` (pointcloud_to_laserscan with ``use_inf`` false: ``range_max + 1``). A scanner's
``no_return`` names its driver's way, and :func:`rep117_ranges` turns it into +inf; a scan
that reads mostly so under the wrong ``no_return`` is invalid, and its blinded stop says
which value it read (:func:`blinded_reason`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Sequence, Tuple

import numpy as np

from quadrivio_description.vehicle import GRAVITY

from .costmap import Footprint


@dataclass(frozen=True)
class Rays:
    """How far each ray of a scan saw empty space (the moving-obstacle tracker's test of
    where something was seen through): a ray's direction at angle ``a`` in the laser's plane
    is ``(m00 cos a + m01 sin a, m10 cos a + m11 sin a)`` in base_link's x-y plane, from
    ``origin``."""
    origin: Tuple[float, float]  # [m] the laser in base_link
    m: Tuple[float, float, float, float]  # (m00, m01, m10, m11)
    angle_min: float  # [rad]
    increment: float  # [rad]
    free: np.ndarray  # [m] per ray: its return's range (-inf: range_min); range_max for +inf; NaN (unknown) for NaN
    #                   and finite ranges outside the limits


@dataclass(frozen=True)
class ScanPoints:
    """The valid points of one scan in ``base_link`` [m], and what the scan held."""
    xy: np.ndarray  # N x 2
    n_rays: int
    n_invalid: int  # NaN, or finite outside [range_min, range_max]
    n_too_close: int  # -inf (REP 117)
    rays: Optional[Rays] = None  # None: the points alone (no test of what was seen through)
    n_zero: int = 0  # of the invalid: exactly 0.0 below range_min (no echo, to drivers older than REP 117)
    n_beyond: int = 0  # of the invalid: finite beyond range_max (no echo, to pointcloud_to_laserscan and others)


NO_RETURN = ("inf", "zero", "beyond_max")


def rep117_ranges(ranges: Sequence[float], range_max: float, no_return: str = "inf") -> np.ndarray:
    """A driver's ranges in REP 117's terms: the rays it reports as having seen nothing, in
    its own way ``no_return``, become +inf. ``inf``: REP 117 itself (nothing changes);
    ``zero``: exactly 0.0; ``beyond_max``: a finite range beyond ``range_max``. Such a driver
    cannot tell nothing seen from a window too dirty to see through: with ``zero`` or
    ``beyond_max`` those rays no longer count as invalid, and no longer blind the guard."""
    r = np.asarray(ranges, dtype=float)
    if no_return == "inf":
        return r
    if no_return == "zero":
        return np.where(r == 0.0, np.inf, r)
    if no_return == "beyond_max":
        return np.where(np.isfinite(r) & (r > range_max), np.inf, r)
    raise ValueError(f"no_return {no_return!r}: expected one of {', '.join(NO_RETURN)}")


def blinded_reason(topic: str, n_rays: int, n_invalid: int, n_zero: int, n_beyond: int) -> str:
    """The blinded stop's reason; when most invalid rays read 0.0 or beyond range_max, it
    says so and names the scanner's ``no_return`` that would take them for nothing seen
    (guard_core.h's blindedReason, word for word)."""
    n = max(n_rays, 1)
    out = f"{topic} blinded: {100.0 * n_invalid / n:.0f} % of its rays invalid"
    if 2 * n_zero > n_invalid:
        out += (f", {100.0 * n_zero / n:.0f} % read 0 m: a driver that reports no echo so needs the scanner's "
                "no_return: zero")
    elif 2 * n_beyond > n_invalid:
        out += (f", {100.0 * n_beyond / n:.0f} % beyond range_max: a driver that reports no echo so needs the "
                "scanner's no_return: beyond_max")
    return out


class ScanError(ValueError):
    """A scan that cannot be read (its geometry is inconsistent)."""


def check_scan(n_ranges: int, angle_min: float, angle_max: float, increment: float, range_min: float,
               range_max: float) -> None:
    """Raise :class:`ScanError` naming what is wrong with a scan's geometry."""
    values = (angle_min, angle_max, increment, range_min, range_max)
    if not all(math.isfinite(v) for v in values):
        raise ScanError(f"non-finite geometry (angle_min {angle_min}, angle_max {angle_max}, angle_increment "
                        f"{increment}, range_min {range_min}, range_max {range_max})")
    if increment == 0.0:
        raise ScanError("angle_increment is 0")
    if not 0.0 <= range_min < range_max:
        raise ScanError(f"range_min {range_min} m and range_max {range_max} m are not 0 <= min < max")
    if n_ranges < 1:
        raise ScanError("no ranges")
    expected = int(round((angle_max - angle_min) / increment)) + 1
    if abs(expected - n_ranges) > 1:
        raise ScanError(f"{n_ranges} ranges, but angle_min {angle_min:.4f}, angle_max {angle_max:.4f} and "
                        f"angle_increment {increment:.6f} rad make {expected}")


def scan_points(ranges: Sequence[float], angle_min: float, increment: float, range_min: float, range_max: float,
                mount: Tuple[float, float, float], max_range: float = math.inf,
                rotation: Optional[np.ndarray] = None) -> ScanPoints:
    """The scan's returns as points in ``base_link``, projected on its x-y plane; ``mount``
    is the laser's (x, y, yaw) in base_link [m, m, rad], or with ``rotation`` (its 3 x 3
    rotation into base_link: a laser mounted upside down or tilted) only (x, y) is used.
    Returns beyond ``max_range`` [m] are left out (too far to matter); ``rays`` keeps how far
    each ray saw empty space, those included (a ray the caller set to +inf, e.g. one that hit
    the ground, counts as nothing seen up to ``range_max``)."""
    r = np.asarray(ranges, dtype=float)
    nan = np.isnan(r)
    too_close = np.isneginf(r)
    finite = np.isfinite(r)
    bad = nan | (finite & ((r < range_min) | (r > range_max)))
    use = (finite & ~bad) | too_close
    rr = np.where(too_close, range_min, r)
    use &= rr <= max_range
    idx = np.flatnonzero(use)
    d = rr[idx]
    if rotation is None:
        a = angle_min + increment * idx + mount[2]
        dx, dy = np.cos(a), np.sin(a)
    else:
        a = angle_min + increment * idx
        c, s = np.cos(a), np.sin(a)
        dx = rotation[0, 0] * c + rotation[0, 1] * s
        dy = rotation[1, 0] * c + rotation[1, 1] * s
    xy = np.column_stack([mount[0] + d * dx, mount[1] + d * dy])
    if rotation is None:
        c, s = math.cos(mount[2]), math.sin(mount[2])
        m = (c, -s, s, c)
    else:
        m = tuple(float(v) for v in (rotation[0, 0], rotation[0, 1], rotation[1, 0], rotation[1, 1]))
    free = np.where(finite & ~bad, r, np.where(np.isposinf(r), float(range_max),
                                                np.where(too_close, float(range_min), np.nan)))
    rays = Rays((float(mount[0]), float(mount[1])), m, float(angle_min), float(increment), free)
    return ScanPoints(xy, len(r), int(np.count_nonzero(bad)), int(np.count_nonzero(too_close)), rays,
                      int(np.count_nonzero(bad & (r == 0.0))), int(np.count_nonzero(bad & (r > range_max))))


def sweep(direction: int, h0: float, h1: float, rate: float, speed: float, length: float, ds: float,
          wheelbase: float, ratio: float = 1.0) -> np.ndarray:
    """Poses (K x 3: x, y, theta in the current base_link) every ``ds`` along the next
    ``length`` metres driven in ``direction`` (see the module's docstring); the first is 0."""
    k = max(1, int(math.ceil(length / ds)))
    s = ds * np.arange(k + 1)
    t = s / max(abs(speed), 0.3)  # the handlebar turns by the time it takes to get there
    h = h0 + np.minimum(np.maximum(h1 - h0, -rate * t), rate * t)
    kappa = np.tan(ratio * h) / wheelbase
    dtheta = direction * kappa[:-1] * ds
    theta = np.concatenate([[0.0], np.cumsum(dtheta)])
    mid = theta[:-1] + 0.5 * dtheta  # midpoint rule along each step
    x = np.concatenate([[0.0], np.cumsum(direction * np.cos(mid) * ds)])
    y = np.concatenate([[0.0], np.cumsum(direction * np.sin(mid) * ds)])
    return np.column_stack([x, y, theta])


def inside(fp: Footprint, points: np.ndarray, x: float = 0.0, y: float = 0.0, theta: float = 0.0) -> np.ndarray:
    """Which of the points (N x 2) lie in the footprint at pose (x, y, theta)."""
    c, s = math.cos(theta), math.sin(theta)
    dx, dy = points[:, 0] - x, points[:, 1] - y
    u = c * dx + s * dy
    w = -s * dx + c * dy
    return (u <= fp.front) & (u >= -fp.rear) & (w <= fp.left) & (w >= -fp.right)


@dataclass(frozen=True)
class Free:
    """How far the swept footprint gets before it touches a point."""
    distance: float  # [m] along the path; inf: nothing within the sweep
    point: Optional[Tuple[float, float]]  # the point touched first (base_link), None when none
    index: int  # which point (-1: none)


def free_distance(fp: Footprint, poses: np.ndarray, points: np.ndarray, ds: float) -> Free:
    """Distance along ``poses`` (from :func:`sweep`, ``ds`` apart) before the footprint
    first contains one of ``points``; conservative by one step (a point touched at pose
    ``k`` gives ``(k - 1) ds``, 0 when the footprint holds it already)."""
    if len(points) == 0:
        return Free(math.inf, None, -1)
    reach = fp.circumscribed_radius + float(np.max(np.hypot(poses[:, 0], poses[:, 1])))
    near = np.flatnonzero(points[:, 0] ** 2 + points[:, 1] ** 2 <= reach * reach)
    if len(near) == 0:
        return Free(math.inf, None, -1)
    p = points[near]
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    dx = p[None, :, 0] - poses[:, 0:1]
    dy = p[None, :, 1] - poses[:, 1:2]
    u = c * dx + s * dy
    w = -s * dx + c * dy
    hit = (u <= fp.front) & (u >= -fp.rear) & (w <= fp.left) & (w >= -fp.right)
    rows = np.flatnonzero(hit.any(axis=1))
    if len(rows) == 0:
        return Free(math.inf, None, -1)
    k = int(rows[0])
    j = int(near[int(np.argmax(hit[k]))])
    return Free(max(0.0, (k - 1) * ds), (float(points[j, 0]), float(points[j, 1])), j)


def effective_decel(decel: float, slope: float, floor: float = 0.3) -> float:
    """Braking deceleration on a slope [rad, positive downhill along the motion] [m/s^2]."""
    return max(decel - GRAVITY * math.sin(slope), floor)


def stopping_distance(speed: float, reaction: float, decel: float) -> float:
    """``v t_r + v^2 / (2 a)`` [m] for speed [m/s], reaction time [s], deceleration [m/s^2]."""
    v = abs(speed)
    return v * reaction + v * v / (2.0 * decel)


def allowed_speed(distance: float, reaction: float, decel: float) -> float:
    """The highest speed whose stopping distance is at most ``distance`` [m]: the positive
    root of ``v t + v^2 / (2 a) = d``; 0 for ``d <= 0``, inf for ``d = inf``."""
    if distance <= 0.0:
        return 0.0
    if math.isinf(distance):
        return math.inf
    return decel * (-reaction + math.sqrt(reaction * reaction + 2.0 * distance / decel))
