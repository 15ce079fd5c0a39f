"""Roll and pitch for the obstacle guard and the local obstacle layer: a complementary filter.

The guard needs the slope (its stopping distance grows downhill) and, with a DEM, both
lasers' 3D pose (to tell the ground from an obstacle). The accelerometer alone reads the
vehicle's own acceleration as tilt: a 4 m/s^2 braking is 22 deg of pitch. So the gyro's
rates carry the attitude from sample to sample, and the accelerometer's gravity direction
pulls it back with time constant ``tau``, after the vehicle's acceleration is taken out
of it (``dv/dt`` ahead, from the wheel speed; ``v w_z`` to the left)::

    roll'  = w_x + (w_y sin(roll) + w_z cos(roll)) tan(pitch) + (roll_g  - roll)  / tau
    pitch' = w_y cos(roll) - w_z sin(roll)                    + (pitch_g - pitch) / tau

with ``roll_g, pitch_g`` the tilt of ``f - (dv/dt, v w_z, 0)`` (REP-103: roll positive
right side down, pitch positive nose down). The rates are the Euler angles' exact
kinematics: the small-angle form (``roll' = w_x``, ``pitch' = w_y``) drops the yaw rate's
share, and turning at 0.6 rad/s rolled 5 deg moves the pitch by 3 deg/s that are not there
(on the rough figure eight at 3 m/s its pitch was off by 2.7 deg RMS, 11.8 deg at worst,
against 1.4 and 4.0 here with ``tau`` 4 s; bench/HISTORY.md). While the wheel speed is stale or
jumps faster than ``max_accel`` (a locked or spinning wheel), the accelerometer's pull is
suspended and the gyro alone carries the attitude (with no wheel speed at all, the
accelerometer is taken as it is).

Pure and ROS-free; readings in base_link axes.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

from quadrivio_description.frames import tilt_from_gravity


class Attitude:
    def __init__(self, tau: float = 4.0, max_accel: float = 8.0, speed_timeout: float = 0.25) -> None:
        self.tau, self.max_accel, self.speed_timeout = tau, max_accel, speed_timeout
        self.roll = self.pitch = 0.0
        self.t: Optional[float] = None  # the newest IMU sample's time
        self.started = False
        self.speed: Optional[tuple] = None  # (t, v) newest wheel speed
        self.accel = 0.0  # [m/s^2] the wheel speed's newest slope
        self.accel_ok = False

    def add_speed(self, t: float, v: float) -> None:
        if self.speed is not None and t > self.speed[0]:
            a = (v - self.speed[1]) / (t - self.speed[0])
            self.accel_ok = abs(a) <= self.max_accel
            self.accel = a if self.accel_ok else 0.0
        self.speed = (t, v)

    def add_imu(self, t: float, f: Sequence[float], w: Sequence[float]) -> None:
        """Specific force [m/s^2] and angular rate [rad/s] in base_link."""
        if self.t is not None and t <= self.t:
            return
        fresh = self.speed is not None and t - self.speed[0] <= self.speed_timeout
        v = self.speed[1] if fresh else 0.0
        g = (f[0] - (self.accel if fresh else 0.0), f[1] - v * w[2], f[2])
        roll_g, pitch_g = tilt_from_gravity(g)
        if not self.started:
            self.roll, self.pitch, self.started, self.t = roll_g, pitch_g, True, t
            return
        dt = t - self.t
        self.t = t
        sr, cr, tp = math.sin(self.roll), math.cos(self.roll), math.tan(self.pitch)
        self.roll += (w[0] + (w[1] * sr + w[2] * cr) * tp) * dt
        self.pitch += (w[1] * cr - w[2] * sr) * dt
        if (fresh and self.accel_ok) or self.speed is None:
            k = min(1.0, dt / self.tau)
            self.roll += k * (roll_g - self.roll)
            self.pitch += k * (pitch_g - self.pitch)

    def valid(self, now: float, timeout: float) -> bool:
        return self.t is not None and now - self.t <= timeout
