"""Ackermann geometry and the kinematic bicycle model, against values worked out by hand."""
import math

import numpy as np
import pytest

from quadrivio_description.kinematics import (ackermann_wheel_angles, bicycle_step, curvature,
                                             delta_for_curvature, turning_radius, yaw_rate)

L, T = 1.25, 0.979


def test_straight_ahead():
    assert ackermann_wheel_angles(0.0, L, T) == (0.0, 0.0)
    assert turning_radius(0.0, L) == math.inf


def test_hand_worked_example():
    # delta = 0.2 rad: R = L / tan(0.2) = 6.1664 m. Inner (left) wheel turns about a
    # radius of R - T/2 = 5.6770 m: atan(1.25 / 5.6770) = 0.21673 rad; outer: atan(1.25 / 6.6559) = 0.18563 rad.
    left, right = ackermann_wheel_angles(0.2, L, T)
    R = L / math.tan(0.2)
    assert R == pytest.approx(6.16644, abs=1e-4)
    assert left == pytest.approx(math.atan(L / (R - T / 2)), abs=1e-12)
    assert right == pytest.approx(math.atan(L / (R + T / 2)), abs=1e-12)
    assert left == pytest.approx(0.21673, abs=1e-5)
    assert right == pytest.approx(0.18563, abs=1e-5)


@pytest.mark.parametrize("delta", np.linspace(-0.6, 0.6, 25))
def test_ackermann_condition(delta):
    left, right = ackermann_wheel_angles(delta, L, T)
    if abs(delta) < 1e-12:
        assert left == right == 0.0
        return
    # The wheel axes meet on the rear axle line: cot(outer) - cot(inner) = t / L.
    inner, outer = (left, right) if delta > 0 else (-right, -left)
    assert 1 / math.tan(outer) - 1 / math.tan(inner) == pytest.approx(T / L, rel=1e-9)
    assert abs(inner) >= abs(outer)
    # Symmetry: turning the other way mirrors the wheels.
    l2, r2 = ackermann_wheel_angles(-delta, L, T)
    assert (l2, r2) == pytest.approx((-right, -left))


def test_turning_radius_and_curvature():
    for delta in (0.05, 0.2, 0.42, -0.3):
        assert turning_radius(delta, L) == pytest.approx(L / math.tan(delta))
        assert curvature(delta, L) * turning_radius(delta, L) == pytest.approx(1.0)
        assert delta_for_curvature(curvature(delta, L), L) == pytest.approx(delta)
        assert yaw_rate(2.0, delta, L) == pytest.approx(2.0 / turning_radius(delta, L))


def test_bicycle_step_exact_on_circle():
    # A quarter circle of radius R in one step equals many small steps (closed form).
    delta = 0.3
    R = turning_radius(delta, L)
    v = 2.0
    t_quarter = (math.pi / 2) * R / v
    x, y, th = bicycle_step(0.0, 0.0, 0.0, v, delta, L, t_quarter)
    assert (x, y, th) == pytest.approx((R, R, math.pi / 2), abs=1e-9)
    xs, ys, ths = 0.0, 0.0, 0.0
    for _ in range(10000):
        xs, ys, ths = bicycle_step(xs, ys, ths, v, delta, L, t_quarter / 10000)
    assert (xs, ys, ths) == pytest.approx((x, y, th), abs=1e-9)


def test_bicycle_step_straight():
    x, y, th = bicycle_step(1.0, 2.0, math.pi / 4, 3.0, 0.0, L, 2.0)
    assert (x, y, th) == pytest.approx((1.0 + 6.0 / math.sqrt(2), 2.0 + 6.0 / math.sqrt(2), math.pi / 4))


def test_invalid_angle():
    with pytest.raises(ValueError):
        ackermann_wheel_angles(math.pi / 2, L, T)


def test_arc_is_the_bicycle_model_and_clamps_at_the_vehicles_limit():
    """kinematics.arc (smoother, dead reckoning, and by check_predictor the C++ predictor)
    agrees with the exact bicycle integration below the limit, and beyond it the wheels
    turn no further and the calibration's Jacobian column says so."""
    import numpy as np

    from quadrivio_description.kinematics import arc, compose, max_delta
    from quadrivio_description.vehicle import load_vehicle

    v = load_vehicle()
    limit = max_delta(v)
    assert limit == pytest.approx(v.steering.max_angle * v.steering.ratio)
    for h in (0.0, 0.1, -0.3):
        d, _ = arc(0.5, 2.0, h, (1.05, 0.01, 0.97), v.wheelbase, v.steering.ratio, limit)
        x, y, th = bicycle_step(0.0, 0.0, 0.0, 1.05 * 2.0, 0.97 * v.steering.ratio * (h + 0.01), v.wheelbase, 0.5)
        assert np.allclose(compose((0.0, 0.0, 0.0), d), (x, y, th), atol=1e-12)
    d_lim, J = arc(0.5, 2.0, 0.9, (1.0, 0.0, 1.0), v.wheelbase, v.steering.ratio, limit)
    d_at, _ = arc(0.5, 2.0, limit / v.steering.ratio, (1.0, 0.0, 1.0), v.wheelbase, v.steering.ratio, limit)
    assert np.allclose(d_lim, d_at) and np.all(J[:, 1:] == 0.0) and np.any(J[:, 0] != 0.0)
