"""Rotations of sensor mounts: roll, pitch, yaw (URDF/REP-103 convention, ZYX)."""

from __future__ import annotations

import math
from typing import Sequence, Tuple

Vec3 = Tuple[float, float, float]


def rpy_matrix(rpy: Sequence[float]) -> Tuple[Vec3, Vec3, Vec3]:
    """``R = Rz(yaw) Ry(pitch) Rx(roll)`` as rows: maps a vector from the rotated frame into its parent."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return ((cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr),
            (sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr),
            (-sp, cp * sr, cp * cr))


def rotate(rpy: Sequence[float], v: Sequence[float]) -> Vec3:
    """``R(rpy) v``: a vector from a frame mounted with roll, pitch, yaw into its parent."""
    R = rpy_matrix(rpy)
    return tuple(R[i][0] * v[0] + R[i][1] * v[1] + R[i][2] * v[2] for i in range(3))  # type: ignore[return-value]


def level(roll: float, pitch: float, v: Sequence[float]) -> Vec3:
    """A body-frame vector in the levelled (heading-aligned, gravity-vertical) frame."""
    return rotate((roll, pitch, 0.0), v)


def tilt_from_gravity(f: Sequence[float]) -> Tuple[float, float]:
    """Roll and pitch [rad] of a body whose accelerometer reads the specific force ``f`` at rest."""
    fx, fy, fz = f
    return math.atan2(fy, fz), math.atan2(-fx, math.hypot(fy, fz))


def yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    """Yaw [rad] (ZYX) of a quaternion ``(x, y, z, w)``."""
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quaternion_from_yaw(yaw: float) -> Tuple[float, float, float, float]:
    """The quaternion ``(x, y, z, w)`` of a rotation by ``yaw`` [rad] about z."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)
