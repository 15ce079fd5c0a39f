"""NMEA 0183 GPS fixes: GGA + GST (+ RMC) sentences to NavSatFix-shaped fixes.

Parsing is pynmea2's (checksums verified). An epoch is one GGA (position, quality,
HDOP, altitude) with the GST (error standard deviations) and RMC (velocity) of the
same UTC time. Receivers differ in which of them they send and in what order, so:

* a GGA is held until its epoch's GST (diagonal covariance from the GST's standard
  deviations) or until a sentence of another epoch -- or, for a receiver that has sent no
  GST so far, the epoch's RMC -- shows that none is coming; the fix then gets a covariance
  from HDOP x a per-quality error (``HDOP_ERROR``), flagged as approximated;
* a GST that comes before its epoch's GGA (the order some receivers use) is kept and
  completes that GGA on its arrival;
* once an epoch has ended without a GST from a receiver that has never sent one (GGA
  alone, or GGA and RMC), every later GGA is a fix on arrival: nothing will complete it,
  and holding it for the next epoch would deliver every fix one period late.

Altitude is the ellipsoidal height,
GGA's mean-sea-level altitude plus its geoid separation (as NavSatFix wants).

Quality -> sensor_msgs/NavSatStatus: 0 -> NO_FIX (-1), 1 -> FIX (0),
2 and 9 -> SBAS_FIX (1), 4 and 5 -> GBAS_FIX (2); 6 (dead reckoning) -> NO_FIX.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

import pynmea2

NO_FIX, FIX, SBAS_FIX, GBAS_FIX = -1, 0, 1, 2
STATUS_OF_QUALITY = {0: NO_FIX, 1: FIX, 2: SBAS_FIX, 3: FIX, 4: GBAS_FIX, 5: GBAS_FIX, 6: NO_FIX, 9: SBAS_FIX}
COVARIANCE_UNKNOWN, COVARIANCE_APPROXIMATED, COVARIANCE_DIAGONAL_KNOWN = 0, 1, 2
# 1-sigma horizontal error per unit HDOP, by GGA quality [m] (no GST available)
HDOP_ERROR = {1: 4.0, 2: 1.0, 3: 4.0, 4: 0.02, 5: 0.5, 9: 1.0}
KNOT = 1852.0 / 3600.0


@dataclass
class Fix:
    utc: str  # hhmmss.ss of the epoch
    status: int
    latitude: float  # [deg]; NaN without a fix
    longitude: float
    altitude: float  # [m] above the WGS-84 ellipsoid
    covariance: Tuple[float, ...]  # 9 values, ENU diagonal [m^2]
    covariance_type: int
    satellites: int
    hdop: float
    received: float  # receipt time of the GGA (caller's clock)


@dataclass
class Velocity:
    """Velocity over ground from an RMC sentence."""
    utc: str
    east: float  # [m/s]
    north: float  # [m/s]
    received: float


@dataclass
class ParseStats:
    sentences: int = 0
    fixes: int = 0
    errors: Dict[str, int] = field(default_factory=dict)


class NmeaFixParser:
    def __init__(self) -> None:
        self.pending: Optional[Fix] = None
        self.gst_seen = False
        self.early_gst: Optional[Tuple[str, pynmea2.GST]] = None  # (epoch, GST) that came before its GGA
        self.ended_without_gst = 0  # epochs finished without a GST while none was ever seen
        self.stats = ParseStats()
        self.problems: List[str] = []

    def _reject(self, reason: str, line: str) -> None:
        self.stats.errors[reason] = self.stats.errors.get(reason, 0) + 1
        self.problems.append(f"{reason}: {line[:80]!r}")

    def pop_problems(self) -> List[str]:
        out, self.problems = self.problems, []
        return out

    def feed_line(self, line: str, received: float) -> List[Union[Fix, Velocity]]:
        """Parse one sentence; returns the fixes it completes and the velocity it carries."""
        line = line.strip()
        if not line:
            return []
        if not line.startswith("$"):
            self._reject("not a sentence", line)
            return []
        try:
            msg = pynmea2.parse(line, check=True)
        except pynmea2.ChecksumError:
            self._reject("bad checksum", line)
            return []
        except (pynmea2.ParseError, ValueError, AttributeError) as exc:
            self._reject(f"unparsable ({type(exc).__name__})", line)
            return []
        self.stats.sentences += 1
        out: List[Union[Fix, Velocity]] = []
        try:
            utc = self._utc(getattr(msg, "timestamp", None))
            if self.pending is not None and utc and utc != self.pending.utc:  # a new epoch: no GST came
                out.append(self._finish(self.pending, None))
                self.pending = None
            if isinstance(msg, pynmea2.GGA):
                fix = self._from_gga(msg, received)
                early, self.early_gst = self.early_gst, None
                if early is not None and early[0] == fix.utc:
                    out.append(self._finish(fix, early[1]))  # its GST came first
                elif not self.gst_seen and self.ended_without_gst:
                    out.append(self._finish(fix, None))  # a receiver without GST: nothing will complete it
                else:
                    self.pending = fix
            elif isinstance(msg, pynmea2.GST):
                self.gst_seen = True
                if self.pending is not None:
                    out.append(self._finish(self.pending, msg))
                    self.pending = None
                elif utc:
                    self.early_gst = (utc, msg)  # before its GGA
            elif isinstance(msg, pynmea2.RMC):
                if self.pending is not None and not self.gst_seen:  # this receiver sends no GST (so far)
                    out.append(self._finish(self.pending, None))
                    self.pending = None
                if msg.status == "A" and msg.spd_over_grnd not in (None, "") and msg.true_course not in (None, ""):
                    v = float(msg.spd_over_grnd) * KNOT
                    c = math.radians(float(msg.true_course))  # from north, clockwise
                    out.append(Velocity(utc, v * math.sin(c), v * math.cos(c), received))
        except (TypeError, ValueError) as exc:
            self._reject(f"bad field ({exc})", line)
        self.stats.fixes += sum(isinstance(f, Fix) for f in out)
        return out

    @staticmethod
    def _utc(ts) -> str:
        return "" if ts is None else ts.strftime("%H%M%S.%f")[:9]

    def _from_gga(self, m: pynmea2.GGA, received: float) -> Fix:
        quality = int(m.gps_qual or 0)
        status = STATUS_OF_QUALITY.get(quality, NO_FIX)
        hdop = float(m.horizontal_dil) if m.horizontal_dil else math.nan
        sats = int(m.num_sats) if m.num_sats else 0
        if status == NO_FIX or not m.lat:
            return Fix(self._utc(m.timestamp), NO_FIX, math.nan, math.nan, math.nan, (0.0,) * 9, COVARIANCE_UNKNOWN,
                       sats, hdop, received)
        alt = float(m.altitude or 0.0) + float(m.geo_sep or 0.0)
        err = HDOP_ERROR.get(quality, 4.0) * (hdop if math.isfinite(hdop) else 1.0)
        cov = (err ** 2, 0.0, 0.0, 0.0, err ** 2, 0.0, 0.0, 0.0, (2.0 * err) ** 2)
        return Fix(self._utc(m.timestamp), status, m.latitude, m.longitude, alt, cov, COVARIANCE_APPROXIMATED, sats,
                   hdop, received)

    def _finish(self, fix: Fix, gst: Optional[pynmea2.GST]) -> Fix:
        if gst is None and not self.gst_seen:
            self.ended_without_gst += 1
        if gst is not None and fix.status != NO_FIX and gst.std_dev_latitude not in (None, ""):
            sn, se, su = float(gst.std_dev_latitude), float(gst.std_dev_longitude), float(gst.std_dev_altitude)
            fix.covariance = (se * se, 0.0, 0.0, 0.0, sn * sn, 0.0, 0.0, 0.0, su * su)
            fix.covariance_type = COVARIANCE_DIAGONAL_KNOWN
        return fix
