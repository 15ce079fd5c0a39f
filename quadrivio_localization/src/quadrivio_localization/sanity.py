"""Physical sense of a recording's readings, before an estimator sees them.

A unit declared wrong in an import mapping (gauss for microtesla, g for m/s^2) gives
readings off by a round factor. The estimator then fails far from the cause (a GTSAM
"Indeterminate linear system" for a field of 0.9 T) or, worse, runs on. These checks
compare a robust level of the readings with what the Earth gives (and the wheel speed with
the speed the GPS fixes show while moving), and name the unit mistake the factor points
to. ROS-free.
"""

from __future__ import annotations

import bisect
import math
from typing import List, Optional, Sequence, Tuple

EARTH_FIELD = (22e-6, 67e-6)  # [T] the geomagnetic field's strength anywhere on the Earth's surface
FIELD_TYPICAL = 45e-6  # [T]
FIELD_OK = (18e-6, 75e-6)  # [T] plausible, with some of a vehicle's hard iron
FIELD_USABLE = (4.5e-6, 450e-6)  # [T] beyond 10x off the typical field: not a field an estimator can use
GRAVITY = 9.80665  # [m/s^2]
GRAVITY_OK = (8.3, 11.3)  # [m/s^2] the specific force's median magnitude of a ground vehicle

# Unit confusions and the factor each gives (read value over true value)
_FIELD_CONFUSIONS = [(1e6, "tesla declared for microtesla data"), (1e-6, "microtesla declared for tesla data"),
                     (1e4, "tesla declared for gauss data"), (1e-4, "gauss declared for tesla data"),
                     (1e2, "gauss declared for microtesla data"), (1e-2, "microtesla declared for gauss data"),
                     (1e3, "microtesla declared for nanotesla data"), (1e-3, "nanotesla declared for microtesla data"),
                     (1e9, "tesla declared for nanotesla data"), (1e-9, "nanotesla declared for tesla data"),
                     (1e5, "gauss declared for nanotesla data"), (1e-5, "nanotesla declared for gauss data")]


def median(values: Sequence[float]) -> float:
    v = sorted(x for x in values if math.isfinite(x))
    if not v:
        return math.nan
    n = len(v)
    return v[n // 2] if n % 2 else 0.5 * (v[n // 2 - 1] + v[n // 2])


def _likely(factor: float, confusions) -> str:
    """The unit confusion whose factor is closest to ``factor`` (in decades), if within half a decade."""
    best = min(confusions, key=lambda c: abs(math.log10(factor) - math.log10(c[0])))
    return best[1] if abs(math.log10(factor) - math.log10(best[0])) < 0.5 else ""


def check_field(strengths_t: Sequence[float], what: str = "the magnetometer") -> Tuple[str, str]:
    """(level, text) for magnetic field strengths [T]: level "" (plausible), "warn" (outside
    the Earth's range but usable) or "error" (more than 10x off: no estimator can use it)."""
    m = median(strengths_t)
    if not math.isfinite(m) or m <= 0.0:
        return "error", f"{what}: no finite, non-zero field strength in the readings"
    text = f"{what} reads a field of {m * 1e6:.3g} uT (median), where the Earth's is 22-67 uT"
    if FIELD_OK[0] <= m <= FIELD_OK[1]:
        return "", ""
    normalised = [unit for unit, scale in (("tesla", 1.0), ("gauss", 1e-4), ("microtesla", 1e-6))
                  if 0.3 <= m / scale <= 3.0]
    guess = _likely(m / FIELD_TYPICAL, _FIELD_CONFUSIONS)
    if normalised:  # raw numbers about 1: a field normalised to the Earth's (Xsens' "arbitrary units")
        hint = (f": the raw readings are about {m / {'tesla': 1.0, 'gauss': 1e-4, 'microtesla': 1e-6}[normalised[0]]:.2g}"
                f" {normalised[0]}, likely a field normalised to the local Earth field (as Xsens IMUs give it) "
                f"declared as {normalised[0]}: declare unit counts with scale = the site's field strength in tesla")
    elif guess:
        hint = f": likely {guess} (the import mapping's mag unit)"
    else:
        hint = ": a unit or scale mistake (the import mapping's mag unit or scale), or a strong magnetic disturbance"
    level = "warn" if FIELD_USABLE[0] <= m <= FIELD_USABLE[1] else "error"
    return level, text + hint


def check_gravity(specific_forces: Sequence[float], what: str = "the IMU") -> Tuple[str, str]:
    """(level, text) for specific-force magnitudes [m/s^2] of a ground vehicle, whose median is
    gravity's 9.81: in g (1.0) or in cm/s^2 it is a unit mistake."""
    m = median(specific_forces)
    if not math.isfinite(m):
        return "error", f"{what}: no finite acceleration in the readings"
    if GRAVITY_OK[0] <= m <= GRAVITY_OK[1]:
        return "", ""
    factor = m / GRAVITY
    guess = ""
    if 0.7 < 1.0 / factor / GRAVITY < 1.4:  # read 1 where 9.81 was meant
        guess = "the accelerations are in g: set the mapping's imu accel_scale to 9.80665"
    elif abs(math.log10(factor) - 2.0) < 0.3:
        guess = "the accelerations are in cm/s^2: set accel_scale 0.01"
    elif abs(math.log10(factor) - 3.0) < 0.3:
        guess = "the accelerations are in mm/s^2 (or mg read as m/s^2): check accel_scale"
    text = f"{what} reads a specific force of {m:.3g} m/s^2 (median), where gravity alone gives 9.81"
    return "warn" if 0.5 * GRAVITY < m < 2.0 * GRAVITY else "error", \
        text + (f": likely {guess}" if guess else ": a unit or scale mistake (the import mapping's accel_scale)")


SPEED_MIN = 1.0  # [m/s] GPS speeds below this are not compared (the fixes' noise over their spacing)
SPEED_OK = (0.75, 1.33)  # [1] wheel speed over GPS speed: slip, tyre radius and GPS noise stay within this


def gps_speeds(fixes: Sequence[Tuple[float, float, float]], spacing: float = 1.0) -> List[Tuple[float, float, float]]:
    """(t0, t1, speed [m/s]) over spans of at least ``spacing`` s between fixes ``(t, lat,
    lon)`` [s, deg, deg] (a local flat-Earth approximation: spans of metres)."""
    out = []
    k = 0
    R = 6371000.0
    for j in range(1, len(fixes)):
        t0, la0, lo0 = fixes[k]
        t1, la1, lo1 = fixes[j]
        if t1 - t0 < spacing:
            continue
        dn = math.radians(la1 - la0) * R
        de = math.radians(lo1 - lo0) * R * math.cos(math.radians(0.5 * (la0 + la1)))
        if t1 - t0 <= 3.0 * spacing:  # a gap in the fixes is not a span
            out.append((t0, t1, math.hypot(de, dn) / (t1 - t0)))
        k = j
    return out


def check_speed(wheel: Sequence[Tuple[float, float]], fixes: Sequence[Tuple[float, float, float]],
                wheel_radius: float = 0.0, what: str = "the wheel speed") -> Tuple[str, str]:
    """(level, text) for the wheel speeds ``(t, v)`` [s, m/s] against the speed the GPS fixes
    ``(t, lat, lon)`` show while moving: a median ratio far from 1 is a unit mistake (km/h,
    mph, the wheel's rad/s) or a reversed sign. Too little motion to compare: ("", "")."""
    wheel = sorted(wheel)
    times = [t for t, _ in wheel]
    ratios = []
    for t0, t1, v in gps_speeds(fixes):
        if v < SPEED_MIN:
            continue
        i, j = bisect.bisect_left(times, t0), bisect.bisect_right(times, t1)
        if j - i < 2:
            continue
        ratios.append(median([wheel[k][1] for k in range(i, j)]) / v)
    if len(ratios) < 5:
        return "", ""
    m = median(ratios)
    if SPEED_OK[0] <= m <= SPEED_OK[1]:
        return "", ""
    text = (f"{what} is {m:.3g} times the speed the GPS fixes show while moving (median of {len(ratios)} spans "
            f"above {SPEED_MIN:g} m/s)")
    confusions = [(3.6, "km/h taken for m/s: the import mapping's state: wheel_speed: scale 0.27778 (1/3.6)"),
                  (1 / 3.6, "a km/h scale (0.27778) applied to data already in m/s"),
                  (2.23694, "mph taken for m/s: state: wheel_speed: scale 0.44704"),
                  (1 / 2.23694, "an mph scale (0.44704) applied to data already in m/s"),
                  (-1.0, "a reversed sign: a negative state: wheel_speed: scale, or a wheel that counts backwards")]
    if wheel_radius > 0.0:
        confusions.append((1.0 / wheel_radius, f"the wheel's angular speed (rad/s) taken for m/s: state: wheel_speed: "
                                               f"scale {wheel_radius:g} (the wheel radius)"))
    best = min(confusions, key=lambda c: abs(m - c[0]) / abs(c[0]))
    hint = f": likely {best[1]}" if abs(m - best[0]) / abs(best[0]) < 0.12 else \
        ": a unit, scale or sign mistake in the import mapping's state, or wheels that slip throughout"
    return "warn", text + hint


def check_all(field_t: Sequence[float], forces: Sequence[float], wheel: Sequence[Tuple[float, float]] = (),
              fixes: Sequence[Tuple[float, float, float]] = (), wheel_radius: float = 0.0) -> List[Tuple[str, str]]:
    """The non-empty results of every check (readings absent: not checked)."""
    out = []
    if len(field_t):
        out.append(check_field(field_t))
    if len(forces):
        out.append(check_gravity(forces))
    if len(wheel) and len(fixes):
        out.append(check_speed(wheel, fixes, wheel_radius))
    return [r for r in out if r[0]]


def first_error(results: List[Tuple[str, str]]) -> Optional[str]:
    return next((t for level, t in results if level == "error"), None)
