"""Ackermann steering geometry and the kinematic (bicycle) model of the vehicle.

Conventions: angles positive to the left (REP-103), the reference point is the centre
of the rear axle (``base_link``), ``L`` is the wheelbase and ``t`` the front track.
``delta`` is the virtual wheel angle of the bicycle model, ``delta = ratio * h`` for a
handlebar angle ``h``. Used by the simulator (wheel angles), the localization
(motion model) and the trajectory follower (curvature to handlebar).
"""

from __future__ import annotations

import math
from typing import Tuple


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
