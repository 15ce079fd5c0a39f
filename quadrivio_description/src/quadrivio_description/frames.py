"""Rotations: roll, pitch, yaw (URDF/REP-103 convention, ZYX), quaternions ``(x, y, z, w)``
and their matrices; the one home of these conversions for every package."""

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


def rpy_from_quaternion(x: float, y: float, z: float, w: float) -> Vec3:
    """Roll, pitch, yaw [rad] (ZYX, as tf and the URDF) of a unit quaternion ``(x, y, z, w)``."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    return roll, pitch, yaw_from_quaternion(x, y, z, w)


def quaternion_from_rpy(roll: float, pitch: float, yaw: float) -> Tuple[float, float, float, float]:
    """The quaternion ``(x, y, z, w)`` of roll, pitch, yaw [rad] (ZYX)."""
    cr, sr = math.cos(0.5 * roll), math.sin(0.5 * roll)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    cy, sy = math.cos(0.5 * yaw), math.sin(0.5 * yaw)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


def matrix_from_quaternion(x: float, y: float, z: float, w: float) -> Tuple[Vec3, Vec3, Vec3]:
    """The rotation matrix of a unit quaternion ``(x, y, z, w)``, as rows."""
    return ((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)),
            (2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)),
            (2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)))
