"""The one home of quaternion, yaw and roll-pitch-yaw conversions (quadrivio_description.frames):
round trips, and the quaternion's matrix against the roll-pitch-yaw matrix built directly."""
import itertools
import math

import numpy as np
import pytest

from quadrivio_description.frames import (matrix_from_quaternion, quaternion_from_rpy, quaternion_from_yaw,
                                          rotate, rpy_from_quaternion, rpy_matrix, yaw_from_quaternion)

ANGLES = list(itertools.product((-0.6, 0.0, 0.4), (-1.2, 0.0, 0.3), (-3.0, -0.5, 0.0, 2.0, math.pi)))


@pytest.mark.parametrize("rpy", ANGLES)
def test_roll_pitch_yaw_round_trip_and_matrix(rpy):
    q = quaternion_from_rpy(*rpy)
    assert sum(c * c for c in q) == pytest.approx(1.0)
    back = rpy_from_quaternion(*q)
    assert back[:2] == pytest.approx(rpy[:2], abs=1e-12)
    assert math.remainder(back[2] - rpy[2], 2 * math.pi) == pytest.approx(0.0, abs=1e-12)
    np.testing.assert_allclose(matrix_from_quaternion(*q), rpy_matrix(rpy), atol=1e-12)
    v = (0.3, -1.1, 2.0)
    np.testing.assert_allclose(np.array(matrix_from_quaternion(*q)) @ v, rotate(rpy, v), atol=1e-12)


def test_yaw_alone_and_a_quaternion_of_either_sign():
    for yaw in (-3.0, -0.2, 0.0, 1.0, 3.1):
        q = quaternion_from_yaw(yaw)
        assert q == pytest.approx(quaternion_from_rpy(0.0, 0.0, yaw))
        assert yaw_from_quaternion(*q) == pytest.approx(yaw)
        assert yaw_from_quaternion(*(-c for c in q)) == pytest.approx(yaw)  # q and -q: the same rotation
