"""InputGuard: what a node lets through, and what it counts."""
import math

import pytest

from quadrivio_runtime.guards import InputGuard, finite


def test_finite():
    assert finite(1.0, -2.0, 0.0) and not finite(1.0, math.nan) and not finite(math.inf)
    assert not finite("x")


def test_stamps():
    g = InputGuard(max_future=0.5, max_age=10.0)
    assert g.stamp("imu", 99.8, 100.0) and g.stamp("imu", 100.4, 100.0)
    assert not g.stamp("imu", 1100.0, 100.0)
    assert not g.stamp("imu", 80.0, 100.0)
    assert not g.stamp("imu", math.nan, 100.0) and not g.stamp("imu", -1.0, 100.0)
    assert g.stamp("imu", 5000.0, 0.0)  # no clock yet: nothing to compare with
    assert g.counts[("imu", "stamp from the future")] == 1 and g.counts[("imu", "stamp too old")] == 1
    assert g.counts[("imu", "bad stamp")] == 2 and g.total == 4
    assert "1000.000 s ahead" not in g.last and "imu: bad stamp" in g.last


def test_values_and_summary():
    logged = []
    g = InputGuard(log=logged.append)
    assert g.check("state", 1.0, 1.0, 0.5, 0.1)
    assert not g.check("state", 1.0, 1.0, math.nan, 0.1)
    assert not g.check("gps", 1.0, 1.0, math.inf)
    assert g.by_input() == {"state": 1, "gps": 1}
    assert g.summary() == "gps: 1 x value not finite; state: 1 x value not finite"
    assert len(logged) == 2 and "nan" in logged[0]
    assert InputGuard().summary() == "none"


def test_bad_limits():
    with pytest.raises(ValueError):
        InputGuard(max_future=-1.0)
