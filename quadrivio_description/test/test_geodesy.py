"""WGS-84 conversions: round trips and hand-checked values."""
import math

import pytest

from quadrivio_description.geodesy import A, B, LocalFrame, ecef_to_lla, lla_to_ecef
from quadrivio_description.site import load_site


def test_known_ecef_points():
    assert lla_to_ecef(0.0, 0.0, 0.0) == pytest.approx((A, 0.0, 0.0))
    assert lla_to_ecef(90.0, 0.0, 0.0) == pytest.approx((0.0, 0.0, B), abs=1e-6)
    assert lla_to_ecef(0.0, 90.0, 100.0) == pytest.approx((0.0, A + 100.0, 0.0), abs=1e-6)


@pytest.mark.parametrize("lat,lon,alt", [(45.478, 9.2277, 165.0), (-33.9, 151.2, 20.0), (0.0, -179.9, -30.0),
                                         (89.9, 10.0, 1000.0)])
def test_round_trip(lat, lon, alt):
    la, lo, h = ecef_to_lla(*lla_to_ecef(lat, lon, alt))
    assert (la, lo) == pytest.approx((lat, lon), abs=1e-10)
    assert h == pytest.approx(alt, abs=1e-4)


def test_local_frame_axes():
    f = LocalFrame(45.0, 9.0, 100.0)
    assert f.lla_to_enu(45.0, 9.0, 100.0) == pytest.approx((0.0, 0.0, 0.0), abs=1e-6)
    e, n, u = f.lla_to_enu(45.0 + 1e-4, 9.0, 100.0)  # north by one ten-thousandth of a degree
    # Meridian radius of curvature at 45 deg: M = a (1 - e2) / (1 - e2 sin^2)^1.5 = 6367381.8 m
    assert n == pytest.approx((6367381.8 + 100.0) * math.radians(1e-4), rel=1e-6)  # at 100 m height
    assert abs(e) < 1e-6 and abs(u) < 1e-3
    e, n, u = f.lla_to_enu(45.0, 9.0 + 1e-4, 100.0)
    assert e > 0 and abs(n) < 1e-3


def test_site_frame_round_trip():
    frame = load_site().local_frame()
    for enu in [(0.0, 0.0, 0.0), (100.0, -50.0, 2.0), (-3000.0, 2500.0, -10.0)]:
        assert frame.lla_to_enu(*frame.enu_to_lla(*enu)) == pytest.approx(enu, abs=1e-6)
