"""Roll and pitch from the accelerometer, and sensor readings turned into the level frame.

The smoother works in the plane: it needs the yaw rate about the vertical and the
horizontal part of the magnetic field. Both come from body-frame readings rotated by
roll and pitch, which the accelerometer gives once the vehicle's own acceleration is
taken out: ``dv/dt`` ahead and ``v * yaw rate`` to the left (without this, every turn
would look like a roll and leak the large vertical field into the levelled
magnetometer). The smoother and the magnetometer calibration share this class, so a
calibration is fitted to exactly the readings the smoother will see.

The wheel speed says the vehicle's acceleration only while it arrives. When it stops (a
frozen PLC client, a dropped link), a sample later than the newest speed by more than
``stale_after`` (or three of the stream's own intervals, if longer) is levelled as
unaccelerated: the last interval's slope extrapolated would be a tilt. It was: a client
frozen while the vehicle sped up at 2.2 m/s^2 left that slope in for the 9.6 s the vehicle
stood braked, the pitch read 12.5 deg, the magnetometer levelled with it turned the
heading 0.5 rad, and the fixes that came back were taken for multipath.

Only samples whose specific force is within ``GRAVITY_BAND`` of 1 g say where gravity is:
a driver starting up (zeros, or a filter ramping up from them), a vehicle dropping onto
its suspension, a shock on rough ground do not. The first accepted samples are averaged
with equal weight until ``tau`` has passed, so one early sample does not set the tilt
for seconds.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from typing import List, Optional, Sequence, Tuple

from quadrivio_description.frames import Vec3, level, rotate, tilt_from_gravity
from quadrivio_description.vehicle import VehicleParams


def lowpass(prev: Optional[float], value: float, t_prev: Optional[float], t: float, tau: float) -> float:
    """First-order low-pass step from ``(t_prev, prev)`` to ``t`` with time constant ``tau``."""
    if prev is None or t_prev is None or tau <= 0.0:
        return value
    a = math.exp(-max(0.0, t - t_prev) / tau)
    return a * prev + (1.0 - a) * value


G = 9.80665  # [m/s^2]
GRAVITY_BAND = 0.3  # a sample whose |specific force| is more than this fraction off 1 g leaves the tilt as it is


class Leveller:
    """Feed wheel speeds and IMU samples in time order; level gyro and magnetometer readings."""

    def __init__(self, vehicle: VehicleParams, tilt_tau: float, stale_after: float = 0.25) -> None:
        self.imu_mount = vehicle.sensors["imu_link"].rpy
        self.mag_mount = vehicle.sensors["mag_link"].rpy
        self.tau = tilt_tau
        self.stale_after = stale_after  # [s] a wheel speed older than this says nothing of the acceleration now
        self.roll = self.pitch = 0.0
        self.body: Tuple[Vec3, Vec3] = ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))  # the newest IMU sample in base_link
        self.t: Optional[float] = None  # time of the newest sample that set the tilt
        self.t0: Optional[float] = None  # time of the first such sample
        self.n = 0  # samples that set the tilt
        self.rejected = 0  # samples not near 1 g
        self._ts: List[float] = []  # the recent wheel speeds' times (ascending) ...
        self._vs: List[float] = []  # ... and speeds, HISTORY s or more of them
        self.ignore_wheel = False  # the wheels slip: their speed says nothing of the body's acceleration

    HISTORY = 1.0  # [s] of wheel speeds kept: an IMU later than this gets the oldest

    def add_speed(self, t: float, v: float) -> None:
        if self._ts and t <= self._ts[-1]:
            return  # out of order (the smoother counts those)
        self._ts.append(t)
        self._vs.append(v)
        if len(self._ts) > 8 and self._ts[-1] - self._ts[len(self._ts) // 2] > self.HISTORY:
            del self._ts[:len(self._ts) // 2], self._vs[:len(self._vs) // 2]

    def speed_and_accel(self, t: Optional[float] = None) -> Tuple[float, float]:
        """Speed and acceleration at ``t`` (None: the newest): the newest speed at or before
        ``t`` and the slope of the interval it starts (ends, for the newest). An IMU that
        arrives late must not be levelled with the speed of when it arrived: in a braking
        or a turn taken 0.15 s later the centripetal and forward terms are not its own.
        Past the newest speed by more than :meth:`stale` s: that speed and no acceleration."""
        ts, vs = self._ts, self._vs
        if not ts or self.ignore_wheel:
            return 0.0, 0.0
        if len(ts) < 2:
            return vs[-1], 0.0
        i = len(ts) - 1 if t is None else max(0, bisect_right(ts, t) - 1)
        if i == len(ts) - 1 and t is not None and t - ts[-1] > self.stale():
            return vs[i], 0.0
        a, b = (i - 1, i) if i == len(ts) - 1 else (i, i + 1)
        return vs[i], (vs[b] - vs[a]) / (ts[b] - ts[a])

    def stale(self) -> float:
        """How long past the newest wheel speed its acceleration is still believed [s]:
        ``stale_after``, or three of the stream's newest intervals for a slower stream."""
        ts = self._ts
        return max(self.stale_after, 3.0 * (ts[-1] - ts[-2])) if len(ts) >= 2 else self.stale_after

    def add_imu(self, t: float, f: Sequence[float], w: Sequence[float]) -> float:
        """Update the tilt from one IMU sample; returns the yaw rate about the vertical [rad/s].
        The sample in base_link axes is kept in :attr:`body` (f, w) for the other users."""
        fb, wb = rotate(self.imu_mount, f), rotate(self.imu_mount, w)
        self.body = (fb, wb)
        v, dv = self.speed_and_accel(t)
        g = (fb[0] - dv, fb[1] - v * wb[2], fb[2])
        if abs(math.sqrt(g[0] ** 2 + g[1] ** 2 + g[2] ** 2) / G - 1.0) > GRAVITY_BAND:
            self.rejected += 1
            return level(self.roll, self.pitch, wb)[2]
        r, p = tilt_from_gravity(g)
        if self.t is None:
            self.t0 = t
        self.n += 1
        if self.tau <= 0.0 or self.t is None:
            a = 1.0
        else:
            a = 1.0 - math.exp(-max(0.0, t - self.t) / self.tau)
            if t - self.t0 < self.tau:  # still the mean of the samples so far
                a = max(a, 1.0 / self.n)
        self.roll += a * (r - self.roll)
        self.pitch += a * (p - self.pitch)
        self.t = t
        return level(self.roll, self.pitch, wb)[2]

    def level_mag(self, m: Sequence[float]) -> Tuple[float, float]:
        """Horizontal components (x ahead, y left, levelled) of a magnetometer reading."""
        mb = level(self.roll, self.pitch, rotate(self.mag_mount, m))
        return mb[0], mb[1]
