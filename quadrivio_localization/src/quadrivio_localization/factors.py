"""Measurement models of the smoother, as GTSAM custom factors with analytic Jacobians.

Poses are ``gtsam.Pose2`` (x, y, theta of base_link in map). GTSAM perturbs a Pose2 on
the right, in the body frame: ``X' = X * Exp(xi)`` with ``xi = (dx_b, dy_b, dtheta)``, so
a Jacobian with respect to world coordinates ``(t, theta)`` becomes, with respect to
``xi``: ``[dE/dt R(theta), dE/dtheta]``. Calibration variables are plain vectors.

Models (``e`` is the error, measurement subtracted):

* odometry (Ackermann, rear axle):  ``e = [t_{k+1} - t_k - R_k D_xy(c); theta_{k+1} - theta_k - D_theta(c)]``
  where ``D(c)`` is the arc the kinematic bicycle model drives over the interval at its
  time-averaged wheel speed and handlebar, with calibration ``c = (k_v, h_0, k_d)``:
  speed ``k_v v``, virtual wheel angle ``k_d * ratio * (h + h_0)``;
* gyro: ``e = theta_{k+1} - theta_k - (sum w_i dt_i - b T)`` with bias ``b``;
* GPS: ``e = t_k + R_k l + g_k - z`` for antenna lever arm ``l``, fix ``z`` (ENU) and the
  receiver's drift ``g_k`` (a Gauss-Markov process, one value per keyframe);
* magnetometer: ``e = S R_k^T h + o - m`` for Earth's horizontal field ``h`` (ENU), the
  levelled horizontal reading ``m`` and calibration ``(o_x, o_y, s_x, s_y, s_xy)``:
  hard iron ``o`` and symmetric soft iron ``S = [[s_x, s_xy], [s_xy, s_y]]``.
"""

from __future__ import annotations

import math
from typing import Sequence, Tuple

import gtsam
import numpy as np

from quadrivio_description import kinematics



def wrap(a: float) -> float:
    """Angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def _rot(theta: float) -> np.ndarray:
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, -s], [s, c]])


# ------------------------------------------------------------------ odometry

def arc(span: float, speed: float, handlebar: float, calib: Sequence[float], wheelbase: float,
        ratio: float, limit: float) -> Tuple[np.ndarray, np.ndarray]:
    """:func:`quadrivio_description.kinematics.arc` (the one implementation)."""
    return kinematics.arc(span, speed, handlebar, calib, wheelbase, ratio, limit)


def odometry_factor(noise, k0: int, k1: int, kc: int, span: float, speed: float, handlebar: float, wheelbase: float,
                    ratio: float, limit: float) -> gtsam.CustomFactor:
    """Between ``X_k0`` and ``X_k1`` through calibration ``kc``, from the interval's
    time-averaged wheel speed and handlebar angle (see :func:`arc`).

    The position error is taken in map axes, ``t_1 - t_0 - R_0 D_xy``, not in the body
    frame: with isotropic noise the cost is the same, but the Gauss-Newton information on
    ``theta_0`` is then ``|D_xy|^2 / sigma^2``, from the motion, and not
    ``|t_1 - t_0|^2 / sigma^2``, from the position estimates' jitter: standing still, the
    body-frame form lets GPS noise pose as heading information, and the marginals keep it.
    """
    cos, sin, arc_floats = math.cos, math.sin, kinematics.arc_floats

    # In floats, not numpy: iSAM2 calls this at every relinearisation of the keyframes
    # (30 -> 18 us a call), and the slowest updates are those relinearising a second of them.
    def error(this: gtsam.CustomFactor, values: gtsam.Values, H):
        p0, p1, c = values.atPose2(k0), values.atPose2(k1), values.atVector(kc)
        (dx, dy, dth), cols = arc_floats(span, speed, handlebar, c[0], c[1], c[2], wheelbase, ratio, limit)
        th0 = p0.theta()
        c0, s0 = cos(th0), sin(th0)
        rdx, rdy = c0 * dx - s0 * dy, s0 * dx + c0 * dy  # R0 D_xy
        e = np.array([p1.x() - p0.x() - rdx, p1.y() - p0.y() - rdy, wrap(p1.theta() - th0 - dth)])
        if H is not None:
            th1 = p1.theta()
            c1, s1 = cos(th1), sin(th1)
            # -d(R0 D)/d(theta0) in the last column; the calibration's: -R0 dD_xy, -dD_theta
            H[0] = np.array([[-c0, s0, rdy], [-s0, -c0, -rdx], [0.0, 0.0, -1.0]])
            H[1] = np.array([[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0]])
            H[2] = np.array([[s0 * b - c0 * a for a, b, _ in cols], [-s0 * a - c0 * b for a, b, _ in cols],
                             [-t for _, _, t in cols]])
        return e
    return gtsam.CustomFactor(noise, [k0, k1, kc], error)


# ---------------------------------------------------------------------- gyro

def gyro_factor(noise, k0: int, k1: int, kb: int, dtheta: float, span: float) -> gtsam.CustomFactor:
    """``dtheta`` = sum of vertical rates x dt over the interval of length ``span``."""
    J0, J1, Jb = np.array([[0.0, 0.0, -1.0]]), np.array([[0.0, 0.0, 1.0]]), np.array([[span]])

    def error(this, values, H):
        b = values.atVector(kb)[0]
        e = np.array([wrap(values.atPose2(k1).theta() - values.atPose2(k0).theta() - (dtheta - b * span))])
        if H is not None:
            H[0], H[1], H[2] = J0, J1, Jb
        return e
    return gtsam.CustomFactor(noise, [k0, k1, kb], error)


# ----------------------------------------------------------------------- GPS

def gps_factor(noise, k: int, kg: int, z: Sequence[float], lever: Sequence[float]) -> gtsam.CustomFactor:
    """``e = t_k + R_k l + g_k - z``: the antenna plus the receiver's slowly drifting bias ``g_k``."""
    zz, l = np.asarray(z, float), np.asarray(lever, float)

    def error(this, values, H):
        p = values.atPose2(this.keys()[0])
        g = values.atVector(this.keys()[1])
        R = _rot(p.theta())
        e = np.array([p.x(), p.y()]) + R @ l + g - zz
        if H is not None:
            J = np.zeros((2, 3))
            J[:, 0:2] = R
            J[:, 2] = R @ np.array([-l[1], l[0]])
            H[0] = J
            H[1] = np.eye(2)
        return e
    return gtsam.CustomFactor(noise, [k, kg], error)


def gps_antenna(pose: gtsam.Pose2, lever: Sequence[float]) -> np.ndarray:
    return np.array([pose.x(), pose.y()]) + _rot(pose.theta()) @ np.asarray(lever, float)


# -------------------------------------------------------------- magnetometer

def mag_predict(theta: float, calib: Sequence[float], h_en: Sequence[float]) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Predicted levelled reading, and its Jacobians w.r.t. theta and the calibration."""
    ox, oy, sx, sy, sxy = calib
    c, s = math.cos(theta), math.sin(theta)
    bx, by = c * h_en[0] + s * h_en[1], -s * h_en[0] + c * h_en[1]  # R(theta)^T h
    S = np.array([[sx, sxy], [sxy, sy]])
    m = S @ np.array([bx, by]) + np.array([ox, oy])
    dm_dth = S @ np.array([by, -bx])
    dm_dc = np.array([[1.0, 0.0, bx, 0.0, by], [0.0, 1.0, 0.0, by, bx]])
    return m, dm_dth, dm_dc


def mag_factor(noise, k: int, kc: int, m: Sequence[float], h_en: Sequence[float]) -> gtsam.CustomFactor:
    mm = np.asarray(m, float)

    def error(this, values, H):
        p = values.atPose2(this.keys()[0])
        c = values.atVector(this.keys()[1])
        pred, dth, dc = mag_predict(p.theta(), c, h_en)
        if H is not None:
            J = np.zeros((2, 3))
            J[:, 2] = dth
            H[0] = J
            H[1] = dc
        return pred - mm
    return gtsam.CustomFactor(noise, [k, kc], error)


def mag_heading(m: Sequence[float], calib: Sequence[float], h_en: Sequence[float]) -> float:
    """Heading that explains a levelled reading ``m`` under calibration ``calib``."""
    ox, oy, sx, sy, sxy = calib
    b = np.linalg.solve(np.array([[sx, sxy], [sxy, sy]]), np.asarray(m, float) - np.array([ox, oy]))
    # b = R(theta)^T h  ->  theta = angle(h) - angle(b)
    return wrap(math.atan2(h_en[1], h_en[0]) - math.atan2(b[1], b[0]))


def gauss_markov_factor(noise, k0: int, k1: int, phi: float) -> gtsam.CustomFactor:
    """First-order Gauss-Markov step between vector variables: ``e = x1 - phi x0`` (with
    ``noise`` of std ``s sqrt(1 - phi^2)`` for a process of stationary std ``s``). Unlike a
    random walk, it pulls back to zero: a drift that is stationary stays bounded, and so
    does what it can hide."""

    def error(this, values, H):
        x0, x1 = values.atVector(this.keys()[0]), values.atVector(this.keys()[1])
        if H is not None:
            n = len(x0)
            H[0] = -phi * np.eye(n)
            H[1] = np.eye(n)
        return x1 - phi * x0

    return gtsam.CustomFactor(noise, [k0, k1], error)


def constant_velocity_factor(noise, k0: int, k1: int, k2: int) -> gtsam.CustomFactor:
    """Without odometry, the vehicle keeps its motion: the translation of interval (k1, k2),
    in the body frame at k1, equals that of (k0, k1) in the body frame at k0, to within the
    noise (a random acceleration). Only the translation: the gyro says how the heading turns."""

    def error(this, values, H):
        x0, x1, x2 = (values.atPose2(k) for k in this.keys())
        J01a, J01b, J12a, J12b = (np.zeros((3, 3), order="F") for _ in range(4))
        d01 = x0.between(x1, J01a, J01b)
        d12 = x1.between(x2, J12a, J12b)
        e = np.array([d12.x() - d01.x(), d12.y() - d01.y()])
        if H is not None:
            # between()'s Jacobians are in the result's tangent space, whose translation part
            # moves the translation along the result's rotation.
            T01 = np.hstack([d01.rotation().matrix(), np.zeros((2, 1))])
            T12 = np.hstack([d12.rotation().matrix(), np.zeros((2, 1))])
            H[0] = -T01 @ J01a
            H[1] = T12 @ J12a - T01 @ J01b
            H[2] = T12 @ J12b
        return e

    return gtsam.CustomFactor(noise, [k0, k1, k2], error)
