"""Ackermann steering geometry and the kinematic (bicycle) model of the vehicle.

Conventions: angles positive to the left (REP-103), the reference point is the centre
of the rear axle (``base_link``), ``L`` is the wheelbase and ``t`` the front track.
``delta`` is the virtual wheel angle of the bicycle model, ``delta = ratio * h`` for a
handlebar angle ``h``. Used by the simulator (wheel angles), the localization
(motion model) and the trajectory follower (curvature to handlebar).
"""

from __future__ import annotations

import math
from typing import Sequence, Tuple

import numpy as np


def ackermann_wheel_angles(delta: float, wheelbase: float, track: float) -> Tuple[float, float]:
    """Left and right front wheel angles [rad] for a virtual wheel angle ``delta`` [rad].

    Both wheels turn about the same centre, on the rear axle line at signed radius
    ``R = L / tan(delta)`` (positive: centre on the left)::

        tan(delta_left)  = L tan(delta) / (L - (t/2) tan(delta))
        tan(delta_right) = L tan(delta) / (L + (t/2) tan(delta))

    so the inner wheel turns more than the outer. Written without ``R`` so that
    ``delta = 0`` gives ``(0, 0)`` without a division by zero.
    """
    if not -0.5 * math.pi < delta < 0.5 * math.pi:
        raise ValueError(f"virtual wheel angle {delta} rad is not within (-pi/2, pi/2)")
    k = math.tan(delta)
    half = 0.5 * track
    left = math.atan2(wheelbase * k, wheelbase - half * k)
    right = math.atan2(wheelbase * k, wheelbase + half * k)
    return left, right


def turning_radius(delta: float, wheelbase: float) -> float:
    """Signed turning radius of the rear axle centre, ``R = L / tan(delta)`` [m] (inf when straight)."""
    k = math.tan(delta)
    return math.inf if k == 0.0 else wheelbase / k


def curvature(delta: float, wheelbase: float) -> float:
    """Path curvature of the rear axle centre, ``kappa = tan(delta) / L`` [1/m]."""
    return math.tan(delta) / wheelbase


def delta_for_curvature(kappa: float, wheelbase: float) -> float:
    """Virtual wheel angle that drives curvature ``kappa`` [1/m]: ``delta = atan(L kappa)``."""
    return math.atan(wheelbase * kappa)


def yaw_rate(speed: float, delta: float, wheelbase: float) -> float:
    """Kinematic yaw rate ``omega = v tan(delta) / L`` [rad/s] for rear axle speed ``v`` [m/s]."""
    return speed * math.tan(delta) / wheelbase


def bicycle_step(x: float, y: float, theta: float, speed: float, delta: float, wheelbase: float,
                 dt: float) -> Tuple[float, float, float]:
    """Integrate the kinematic bicycle model exactly over ``dt`` for constant ``speed`` and ``delta``.

    ``x' = v cos(theta)``, ``y' = v sin(theta)``, ``theta' = v tan(delta) / L``: the
    rear axle centre moves on an arc (a line when ``delta = 0``).
    """
    w = yaw_rate(speed, delta, wheelbase)
    dtheta = w * dt
    if abs(dtheta) < 1e-9:
        c, s = math.cos(theta + 0.5 * dtheta), math.sin(theta + 0.5 * dtheta)
        return x + speed * dt * c, y + speed * dt * s, theta + dtheta
    r = speed / w
    return (x + r * (math.sin(theta + dtheta) - math.sin(theta)),
            y - r * (math.cos(theta + dtheta) - math.cos(theta)),
            theta + dtheta)


def max_delta(vehicle) -> float:
    """The virtual wheel angle limit [rad]: the handlebar limit times the steering ratio."""
    return vehicle.steering.max_angle * vehicle.steering.ratio


def _f(a: float) -> Tuple[float, float]:
    """``sin(a) / a`` and its derivative (series near 0)."""
    if abs(a) < 1e-4:
        return 1.0 - a * a / 6.0, -a / 3.0
    return math.sin(a) / a, (a * math.cos(a) - math.sin(a)) / (a * a)


def _g(a: float) -> Tuple[float, float]:
    """``(1 - cos(a)) / a`` and its derivative (series near 0)."""
    if abs(a) < 1e-4:
        return a / 2.0, 0.5 - a * a / 8.0
    return (1.0 - math.cos(a)) / a, (a * math.sin(a) - (1.0 - math.cos(a))) / (a * a)


def arc(span: float, speed: float, handlebar: float, calib: Sequence[float], wheelbase: float, ratio: float,
        limit: float) -> Tuple[np.ndarray, np.ndarray]:
    """The one bicycle arc of the stack (smoother, dead reckoning; the C++ predictor is held
    to it by shared test vectors, ``test/data/bicycle_vectors.yaml``).

    Relative motion ``(dx, dy, dtheta)`` of the rear axle over ``span`` s at constant
    measured ``speed`` and ``handlebar``, with calibration ``(k_v, h_0, k_d)``, and its
    Jacobian with respect to the calibration::

        s = k_v v T,  delta = clamp(k_d ratio (h + h_0), +-limit),  kappa = tan(delta) / L,
        dtheta = s kappa,  dx = s sin(dtheta) / dtheta,  dy = s (1 - cos(dtheta)) / dtheta

    ``limit`` is the vehicle's virtual wheel angle limit (:func:`max_delta`): whatever the
    calibration says, the wheels turn no further (and the Jacobian says so: zero).
    """
    out, cols = arc_floats(span, speed, handlebar, calib[0], calib[1], calib[2], wheelbase, ratio, limit)
    return np.array(out), np.array(cols).T


def arc_floats(span: float, speed: float, handlebar: float, k_v: float, h0: float, k_d: float, wheelbase: float,
               ratio: float, limit: float):
    """:func:`arc` in plain floats, for the smoother's odometry factor (called at every
    relinearisation, where numpy's per-array cost was most of its time): ``(dx, dy,
    dtheta)`` and the Jacobian's three columns, d/dk_v, d/dh_0, d/dk_d."""
    vt = speed * span
    s = k_v * vt
    raw = k_d * ratio * (handlebar + h0)
    delta = max(-limit, min(limit, raw))
    kappa = math.tan(delta) / wheelbase
    dth = s * kappa
    f, df = _f(dth)
    g, dg = _g(dth)
    dth_kv = vt * kappa  # d/dk_v: ds = vt
    col_kv = (vt * f + s * df * dth_kv, vt * g + s * dg * dth_kv, dth_kv)
    if delta != raw:  # clamped: the calibration does not move the wheels
        col_h0 = col_kd = (0.0, 0.0, 0.0)
    else:  # d/d(delta): ds = 0, d(dtheta) = s sec^2(delta) / L
        dth_d = s / (math.cos(delta) ** 2 * wheelbase)
        a, b = k_d * ratio, ratio * (handlebar + h0)
        col_h0 = (s * df * dth_d * a, s * dg * dth_d * a, dth_d * a)
        col_kd = (s * df * dth_d * b, s * dg * dth_d * b, dth_d * b)
    return (s * f, s * g, dth), (col_kv, col_h0, col_kd)


def compose(pose: Tuple[float, float, float], d: Sequence[float]) -> Tuple[float, float, float]:
    """``pose`` moved by the relative motion ``d = (dx, dy, dtheta)`` in its own frame."""
    x, y, th = pose
    c, s = math.cos(th), math.sin(th)
    return x + c * d[0] - s * d[1], y + s * d[0] + c * d[1], th + d[2]
