"""The smoother's measurement models: analytic Jacobians against finite differences, and
the closed-form arc against integrating the bicycle model."""
import math

import gtsam
import numpy as np
import pytest

from quadrivio_localization import factors as F

X, K, B, M, G = (gtsam.symbol_shorthand.X, gtsam.symbol_shorthand.K, gtsam.symbol_shorthand.B,
                 gtsam.symbol_shorthand.M, gtsam.symbol_shorthand.G)
UNIT = {n: gtsam.noiseModel.Unit.Create(n) for n in (1, 2, 3)}


def retract(values, key, delta):
    out = gtsam.Values(values)
    try:
        out.update(key, values.atPose2(key).retract(delta))
    except RuntimeError:
        out.update(key, values.atVector(key) + delta)
    return out


def dim(values, key):
    try:
        values.atPose2(key)
        return 3
    except RuntimeError:
        return len(values.atVector(key))


def check_jacobians(factor, values, eps=1e-6, tol=1e-5):
    A, b = factor.linearize(values).jacobian()  # unit noise: A = H, b = -error
    e0 = factor.unwhitenedError(values)
    np.testing.assert_allclose(-b, e0, atol=1e-12)
    col = 0
    for key in factor.keys():
        for i in range(dim(values, key)):
            d = np.zeros(dim(values, key))
            d[i] = eps
            num = (factor.unwhitenedError(retract(values, key, d)) -
                   factor.unwhitenedError(retract(values, key, -d))) / (2 * eps)
            np.testing.assert_allclose(A[:, col], num, atol=tol, err_msg=f"{gtsam.Symbol(key).string()}[{i}]")
            col += 1


@pytest.mark.parametrize("speed,handlebar", [(2.0, 0.2), (0.0, 0.0), (-1.0, -0.3), (3.0, 1e-7)])
def test_odometry_jacobians(speed, handlebar):
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(1.0, -2.0, 0.7))
    v.insert(X(1), gtsam.Pose2(1.1, -1.9, 0.75))
    v.insert(K(0), np.array([1.02, 0.01, 0.97]))
    check_jacobians(F.odometry_factor(UNIT[3], X(0), X(1), K(0), 0.05, speed, handlebar, 1.25, 0.9, 1.4), v)


def test_odometry_at_rest_carries_no_heading_information():
    """Standing still, jittering position estimates must not pose as heading information."""
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(0.0, 0.0, 0.3))
    v.insert(X(1), gtsam.Pose2(0.01, -0.02, 0.3))
    v.insert(K(0), np.array([1.0, 0.0, 1.0]))
    A, _ = F.odometry_factor(UNIT[3], X(0), X(1), K(0), 0.05, 0.0, 0.0, 1.25, 0.9, 1.4).linearize(v).jacobian()
    assert np.allclose(A[:2, 2], 0.0)


def test_arc_matches_integrated_bicycle():
    L, ratio, calib = 1.25, 0.9, (1.05, 0.02, 0.95)
    (dx, dy, dth), _ = F.arc(1.0, 2.0, 0.3, calib, L, ratio, 1.4)
    x = y = th = 0.0
    n = 100000
    delta = calib[2] * ratio * (0.3 + calib[1])
    for _ in range(n):
        ds = calib[0] * 2.0 / n
        x += ds * math.cos(th + 0.5 * ds * math.tan(delta) / L)
        y += ds * math.sin(th + 0.5 * ds * math.tan(delta) / L)
        th += ds * math.tan(delta) / L
    assert (dx, dy, dth) == pytest.approx((x, y, th), abs=1e-6)


def test_gyro_jacobians():
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(0.0, 0.0, 3.1))
    v.insert(X(1), gtsam.Pose2(0.1, 0.0, -3.1))  # across the wrap
    v.insert(B(0), np.array([0.003]))
    f = F.gyro_factor(UNIT[1], X(0), X(1), B(0), 0.08, 0.05)
    check_jacobians(f, v)
    assert abs(f.unwhitenedError(v)[0]) < 0.2


def test_gps_jacobians():
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(3.0, 4.0, -1.2))
    v.insert(G(0), np.array([0.1, -0.2]))
    check_jacobians(F.gps_factor(UNIT[2], X(0), G(0), (3.5, 4.2), (-0.15, 0.05)), v)


def test_mag_jacobians_and_heading_inverse():
    h = (1.1, 24.2)
    calib = np.array([4.0, -2.5, 1.05, 0.96, 0.03])
    v = gtsam.Values()
    v.insert(X(0), gtsam.Pose2(0.0, 0.0, 0.9))
    v.insert(M(0), calib)
    m, _, _ = F.mag_predict(0.9, calib, h)
    f = F.mag_factor(UNIT[2], X(0), M(0), m + np.array([0.3, -0.2]), h)
    check_jacobians(f, v)
    assert F.mag_heading(m, calib, h) == pytest.approx(0.9, abs=1e-9)
