"""Where the vehicle operates: the map frame's datum and Earth's magnetic field there.

Loaded from ``config/site.yaml`` into ``/site`` by the launch files and read by the
simulator (magnetometer), the GPS adapter (ENU -> latitude/longitude) and the
localization (fixes -> map frame, magnetic heading).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

from quadrivio_config import from_mapping, load_yaml, param
from .geodesy import LocalFrame
from .vehicle import package_dir


@dataclass(frozen=True)
class Datum:
    latitude: float = param(lo=-90.0, hi=90.0, unit="deg", doc="map frame origin, WGS-84 latitude")
    longitude: float = param(lo=-180.0, hi=180.0, unit="deg", doc="map frame origin, WGS-84 longitude")
    altitude: float = param(lo=-1000.0, hi=10000.0, unit="m", doc="map frame origin, height above the ellipsoid")


@dataclass(frozen=True)
class MagneticField:
    declination: float = param(lo=-math.pi, hi=math.pi, unit="rad", doc="angle from true to magnetic north, east positive")
    inclination: float = param(lo=-math.pi / 2, hi=math.pi / 2, unit="rad", doc="dip below the horizontal, down positive")
    intensity: float = param(lo=1e-6, hi=1e-3, unit="T", doc="total field intensity")

    def enu(self):
        """The field in ENU [T]: ``B (cos I sin D, cos I cos D, -sin I)``."""
        ci = math.cos(self.inclination)
        return (self.intensity * ci * math.sin(self.declination), self.intensity * ci * math.cos(self.declination),
                -self.intensity * math.sin(self.inclination))


@dataclass(frozen=True)
class SiteParams:
    datum: Datum = param()
    magnetic_field: MagneticField = param()
    utc_epoch: float = param(1780308000.0, lo=0.0, hi=4e9, unit="s",
                             doc="UTC (Unix time) at sim time 0, for simulated GNSS time")

    def local_frame(self) -> LocalFrame:
        return LocalFrame(self.datum.latitude, self.datum.longitude, self.datum.altitude)


def default_site_file() -> str:
    return os.path.join(package_dir(), "config", "site.yaml")


def load_site(path: str = "") -> SiteParams:
    path = path or default_site_file()
    return from_mapping(SiteParams, load_yaml(path), path)
