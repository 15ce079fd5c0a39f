"""Roll and pitch from the accelerometer, and sensor readings turned into the level frame.

The smoother works in the plane: it needs the yaw rate about the vertical and the
horizontal part of the magnetic field. Both come from body-frame readings rotated by
roll and pitch, which the accelerometer gives once the vehicle's own acceleration is
taken out: ``dv/dt`` ahead and ``v * yaw rate`` to the left (without this, every turn
would look like a roll and leak the large vertical field into the levelled
magnetometer). The smoother and the magnetometer calibration share this class, so a
calibration is fitted to exactly the readings the smoother will see.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence, Tuple

from quadrivio_description.frames import level, rotate, tilt_from_gravity
from quadrivio_description.vehicle import VehicleParams


def lowpass(prev: Optional[float], value: float, t_prev: Optional[float], t: float, tau: float) -> float:
    """First-order low-pass step from ``(t_prev, prev)`` to ``t`` with time constant ``tau``."""
    if prev is None or t_prev is None or tau <= 0.0:
        return value
    a = math.exp(-max(0.0, t - t_prev) / tau)
    return a * prev + (1.0 - a) * value


class Leveller:
    """Feed wheel speeds and IMU samples in time order; level gyro and magnetometer readings."""

    def __init__(self, vehicle: VehicleParams, tilt_tau: float) -> None:
        self.imu_mount = vehicle.sensors["imu_link"].rpy
        self.mag_mount = vehicle.sensors["mag_link"].rpy
        self.tau = tilt_tau
        self.roll = self.pitch = 0.0
        self.t: Optional[float] = None
        self._speeds: list = []  # the last two (t, v)

    def add_speed(self, t: float, v: float) -> None:
        self._speeds = (self._speeds + [(t, v)])[-2:]

    def speed_and_accel(self) -> Tuple[float, float]:
        if not self._speeds:
            return 0.0, 0.0
        if len(self._speeds) < 2:
            return self._speeds[-1][1], 0.0
        (t0, v0), (t1, v1) = self._speeds
        return v1, ((v1 - v0) / (t1 - t0) if t1 > t0 else 0.0)

    def add_imu(self, t: float, f: Sequence[float], w: Sequence[float]) -> float:
        """Update the tilt from one IMU sample; returns the yaw rate about the vertical [rad/s]."""
        fb, wb = rotate(self.imu_mount, f), rotate(self.imu_mount, w)
        v, dv = self.speed_and_accel()
        r, p = tilt_from_gravity((fb[0] - dv, fb[1] - v * wb[2], fb[2]))
        first = self.t is None
        self.roll = lowpass(None if first else self.roll, r, self.t, t, self.tau)
        self.pitch = lowpass(None if first else self.pitch, p, self.t, t, self.tau)
        self.t = t
        return level(self.roll, self.pitch, wb)[2]

    def level_mag(self, m: Sequence[float]) -> Tuple[float, float]:
        """Horizontal components (x ahead, y left, levelled) of a magnetometer reading."""
        mb = level(self.roll, self.pitch, rotate(self.mag_mount, m))
        return mb[0], mb[1]
