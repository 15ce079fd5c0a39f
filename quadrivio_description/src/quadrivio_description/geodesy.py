"""WGS-84 geodesy: geodetic <-> ECEF <-> local ENU about a datum (the map frame's origin).

The map frame (REP-105) is East-North-Up with its origin at the GPS datum. The GPS
adapter turns simulated ENU positions into latitude/longitude/altitude with
:meth:`LocalFrame.enu_to_lla`; the localization turns fixes back with
:meth:`LocalFrame.lla_to_enu`. Angles in degrees where the NavSatFix message uses
degrees, radians inside.
"""

from __future__ import annotations

import math
from typing import Tuple

A = 6378137.0  # [m] WGS-84 semi-major axis
F = 1.0 / 298.257223563  # WGS-84 flattening
E2 = F * (2.0 - F)  # first eccentricity squared
B = A * (1.0 - F)  # [m] semi-minor axis
EP2 = (A * A - B * B) / (B * B)  # second eccentricity squared


def lla_to_ecef(lat_deg: float, lon_deg: float, alt: float) -> Tuple[float, float, float]:
    """Geodetic (deg, deg, m above the ellipsoid) to ECEF [m]."""
    lat, lon = math.radians(lat_deg), math.radians(lon_deg)
    s, c = math.sin(lat), math.cos(lat)
    n = A / math.sqrt(1.0 - E2 * s * s)  # prime vertical radius of curvature
    return ((n + alt) * c * math.cos(lon), (n + alt) * c * math.sin(lon), (n * (1.0 - E2) + alt) * s)


def ecef_to_lla(x: float, y: float, z: float) -> Tuple[float, float, float]:
    """ECEF [m] to geodetic (deg, deg, m); Bowring's formula refined by two iterations (< 1 mm)."""
    lon = math.atan2(y, x)
    p = math.hypot(x, y)
    th = math.atan2(z * A, p * B)
    lat = math.atan2(z + EP2 * B * math.sin(th) ** 3, p - E2 * A * math.cos(th) ** 3)
    for _ in range(2):
        n = A / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
        alt = p / math.cos(lat) - n
        lat = math.atan2(z, p * (1.0 - E2 * n / (n + alt)))
    n = A / math.sqrt(1.0 - E2 * math.sin(lat) ** 2)
    alt = p / math.cos(lat) - n
    return math.degrees(lat), math.degrees(lon), alt


class LocalFrame:
    """East-North-Up frame tangent to the ellipsoid at a datum (lat0, lon0, alt0)."""

    def __init__(self, lat0_deg: float, lon0_deg: float, alt0: float) -> None:
        self.lat0, self.lon0, self.alt0 = lat0_deg, lon0_deg, alt0
        self.origin = lla_to_ecef(lat0_deg, lon0_deg, alt0)
        la, lo = math.radians(lat0_deg), math.radians(lon0_deg)
        sl, cl, so, co = math.sin(la), math.cos(la), math.sin(lo), math.cos(lo)
        # Rows: east, north, up unit vectors in ECEF.
        self.R = ((-so, co, 0.0), (-sl * co, -sl * so, cl), (cl * co, cl * so, sl))

    def ecef_to_enu(self, x: float, y: float, z: float) -> Tuple[float, float, float]:
        d = (x - self.origin[0], y - self.origin[1], z - self.origin[2])
        return tuple(r[0] * d[0] + r[1] * d[1] + r[2] * d[2] for r in self.R)  # type: ignore[return-value]

    def enu_to_ecef(self, e: float, n: float, u: float) -> Tuple[float, float, float]:
        R = self.R
        return (self.origin[0] + R[0][0] * e + R[1][0] * n + R[2][0] * u,
                self.origin[1] + R[0][1] * e + R[1][1] * n + R[2][1] * u,
                self.origin[2] + R[0][2] * e + R[1][2] * n + R[2][2] * u)

    def enu_to_lla(self, e: float, n: float, u: float) -> Tuple[float, float, float]:
        return ecef_to_lla(*self.enu_to_ecef(e, n, u))

    def lla_to_enu(self, lat_deg: float, lon_deg: float, alt: float) -> Tuple[float, float, float]:
        return self.ecef_to_enu(*lla_to_ecef(lat_deg, lon_deg, alt))
