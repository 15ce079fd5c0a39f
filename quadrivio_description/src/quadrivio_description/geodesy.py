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


class _Math:
    """The functions the formulas below use, on floats (math) or on arrays (numpy): one
    formula for a fix and for a raster's million pixels."""

    def __init__(self, module) -> None:
        self.sin, self.cos, self.sqrt, self.hypot = module.sin, module.cos, module.sqrt, module.hypot
        self.atan2 = getattr(module, "atan2", None) or module.arctan2
        self.radians, self.degrees = module.radians, module.degrees


_SCALAR = _Math(math)


def _numpy() -> _Math:
    import numpy as np

    return _Math(np)


def _lla_to_ecef(lat_deg, lon_deg, alt, m: _Math):
    lat, lon = m.radians(lat_deg), m.radians(lon_deg)
    s, c = m.sin(lat), m.cos(lat)
    n = A / m.sqrt(1.0 - E2 * s * s)  # prime vertical radius of curvature
    return ((n + alt) * c * m.cos(lon), (n + alt) * c * m.sin(lon), (n * (1.0 - E2) + alt) * s)


def _ecef_to_lla(x, y, z, m: _Math):
    lon = m.atan2(y, x)
    p = m.hypot(x, y)
    th = m.atan2(z * A, p * B)
    lat = m.atan2(z + EP2 * B * m.sin(th) ** 3, p - E2 * A * m.cos(th) ** 3)
    for _ in range(2):
        n = A / m.sqrt(1.0 - E2 * m.sin(lat) ** 2)
        alt = p / m.cos(lat) - n
        lat = m.atan2(z, p * (1.0 - E2 * n / (n + alt)))
    n = A / m.sqrt(1.0 - E2 * m.sin(lat) ** 2)
    alt = p / m.cos(lat) - n
    return m.degrees(lat), m.degrees(lon), alt


def lla_to_ecef(lat_deg: float, lon_deg: float, alt: float) -> Tuple[float, float, float]:
    """Geodetic (deg, deg, m above the ellipsoid) to ECEF [m]."""
    return _lla_to_ecef(lat_deg, lon_deg, alt, _SCALAR)


def ecef_to_lla(x: float, y: float, z: float) -> Tuple[float, float, float]:
    """ECEF [m] to geodetic (deg, deg, m); Bowring's formula refined by two iterations (< 1 mm)."""
    return _ecef_to_lla(x, y, z, _SCALAR)


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

    # the same for arrays (numpy; a raster's pixels): east, north, up [m] <-> lat, lon [deg], alt [m]
    def enu_to_lla_arrays(self, e, n, u):
        import numpy as np

        e, n, u = np.broadcast_arrays(np.asarray(e, float), np.asarray(n, float), np.asarray(u, float))
        return _ecef_to_lla(*self.enu_to_ecef(e, n, u), _numpy())

    def lla_to_enu_arrays(self, lat_deg, lon_deg, alt):
        import numpy as np

        return self.ecef_to_enu(*_lla_to_ecef(np.asarray(lat_deg, float), np.asarray(lon_deg, float),
                                              np.asarray(alt, float), _numpy()))
