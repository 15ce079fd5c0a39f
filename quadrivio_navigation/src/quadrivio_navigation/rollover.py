"""Roll-over risk from the IMU: static stability factor, lateral acceleration, roll angle.

A rigid vehicle on its wheels tips over when the resultant of gravity and the inertial
force, seen in the body frame, passes outside the wheels: with the specific force
``f = (f_x, f_y, f_z)`` measured in ``base_link`` (gravity and acceleration together,
side slopes included), that is ``|f_y / f_z| > SSF``, the static stability factor
``SSF = T / (2 h)`` (mean track ``T``, centre-of-mass height ``h``). The monitor
reports

    risk = |f_y / f_z|_lp / SSF        (1 = on the point of tipping; low-passed, tau)
    roll = complementary filter of the gyro's roll rate and atan2(f_y, f_z)

and its level: TRIP when ``risk >= trip_ratio`` or ``|roll| >= max_roll``, WARN from
``warn_ratio`` or ``warn_fraction * max_roll``; a trip is held for ``hold_time``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

from quadrivio_config import param

OK, WARN, TRIP = 0, 1, 2
AIRBORNE = 0.5  # [g] a specific force below this: not standing on the wheels
LEVEL_NAMES = {OK: "OK", WARN: "WARN", TRIP: "TRIP"}


@dataclass(frozen=True)
class RolloverParams:
    warn_ratio: float = param(0.6, lo=0.05, hi=1.0, doc="warn from this fraction of the static stability factor")
    trip_ratio: float = param(0.85, lo=0.05, hi=1.5, doc="trip (and stop) from this fraction")
    max_roll: float = param(0.5, lo=0.05, hi=1.5, unit="rad", doc="trip at this roll angle whatever the risk")
    warn_fraction: float = param(0.8, lo=0.1, hi=1.0, doc="warn from this fraction of max_roll")
    tau: float = param(0.3, lo=0.0, hi=10.0, unit="s", doc="low-pass time constant of the risk and roll filters")
    hold_time: float = param(2.0, lo=0.0, hi=60.0, unit="s", doc="a trip is held at least this long")

    def __post_init__(self) -> None:
        if self.warn_ratio >= self.trip_ratio:
            raise ValueError(f"'warn_ratio' = {self.warn_ratio} must be below 'trip_ratio' = {self.trip_ratio}")


@dataclass(frozen=True)
class RolloverState:
    stamp: float
    risk: float  # [1] 1 = tipping
    roll: float  # [rad]
    lateral_accel: float  # [m/s^2] f_y in base_link, low-passed
    level: int


class RolloverMonitor:
    MAX_RATIO = 100.0  # |f_y / f_z| used when f_z is about zero or negative

    def __init__(self, p: RolloverParams, ssf: float) -> None:
        if ssf <= 0.0:
            raise ValueError(f"static stability factor {ssf} must be positive")
        self.p, self.ssf = p, ssf
        self.t = None
        self.ratio = 0.0
        self.fy = 0.0
        self.roll = None
        self.trip_until = -math.inf
        self.rejected = 0  # non-finite samples skipped

    def _hold(self, t: float) -> RolloverState:
        """The state without a new sample (airborne, or a non-finite sample)."""
        if self.t is None:
            return RolloverState(t, 0.0, 0.0, 0.0, OK)
        return RolloverState(t, self.ratio / self.ssf, self.roll, self.fy,
                             TRIP if math.isfinite(t) and t < self.trip_until else OK)

    def update(self, t: float, f: Sequence[float], w: Sequence[float]) -> RolloverState:
        """One IMU sample: specific force ``f`` [m/s^2] and angular rate ``w`` [rad/s] in base_link.

        While airborne (``|f| < AIRBORNE * g``: a jump, a drop) the body-frame ratio says
        nothing about tipping: the sample is skipped. ``f_z`` clearly negative means the
        vehicle is on its side or upside down.
        """
        if not all(math.isfinite(x) for x in (t, *f, *w)):
            self.rejected += 1  # one NaN or inf must not latch the filter (or a trip) for good
            return self._hold(t)
        fy, fz = f[1], f[2]
        if math.sqrt(f[0] ** 2 + fy ** 2 + fz ** 2) < AIRBORNE * 9.81:
            return self._hold(t)
        # On its side or upside down: far beyond any trip ratio, but finite, so that the
        # filter comes back once the vehicle is upright again.
        ratio = min(abs(fy / fz), self.MAX_RATIO) if fz > 1e-3 else self.MAX_RATIO
        roll_acc = math.atan2(fy, fz)
        if self.t is None or self.p.tau == 0.0:
            dt, alpha = 0.0, 0.0
            self.ratio, self.fy, self.roll = ratio, fy, roll_acc
        else:
            dt = max(0.0, t - self.t)
            alpha = self.p.tau / (self.p.tau + dt) if dt > 0 else 1.0
            self.ratio = alpha * self.ratio + (1 - alpha) * ratio
            self.fy = alpha * self.fy + (1 - alpha) * fy
            self.roll = alpha * (self.roll + w[0] * dt) + (1 - alpha) * roll_acc
        self.t = t
        risk = self.ratio / self.ssf
        if risk >= self.p.trip_ratio or abs(self.roll) >= self.p.max_roll:
            self.trip_until = t + self.p.hold_time
        if t < self.trip_until:
            level = TRIP
        elif risk >= self.p.warn_ratio or abs(self.roll) >= self.p.warn_fraction * self.p.max_roll:
            level = WARN
        else:
            level = OK
        return RolloverState(t, risk, self.roll, self.fy, level)
