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

Two biases are taken out, both found on the rough figure eight at 3 m/s, where the pitch
read 1.0 deg nose down on average whenever the body pitched down (the front laser's plane
then meets the ground a few metres ahead: 0.06 m of height at 3.5 m, and the returns fell
just outside the guard's ground tolerance: false stops):

* **the IMU's lever arm** ``lever`` (its position in base_link): the accelerometer also
  feels the centripetal ``w x (w x r)``, never zero on average: ``-r_x w^2`` along x when
  the body pitches on bumps (0.55 m x 0.3 rad^2/s^2 is 1 deg of tilt) or turns (0.6 rad/s:
  1.1 deg); subtracted with the gyro's rates. The angular acceleration's share
  ``alpha x r`` is left: from the gyro differenced at 100 Hz it was noise, and taken out it
  moved the rough run's pitch error from -0.14 to +0.54 deg (the body does not pitch about
  base_link);
* **the gyro's bias** (a PI complementary filter, as Mahony's): a proportional pull alone
  leaves a steady error of bias x ``tau``, 0.7 deg for a MEMS gyro's 3e-3 rad/s turn-on
  bias at 4 s. The pull's error is integrated into the rates::

      b_roll' = -(roll_g - roll) / (4 tau^2),  b_pitch' = -(pitch_g - pitch) / (4 tau^2)

  subtracted from the Euler rates (critically damped: about 40 s to learn a bias at
  ``tau`` 4 s), each bounded by ``max_bias``, frozen while the pull is suspended.

Together: a pitch error of -0.14 +- 0.58 deg at those scans, against +1.02 +- 1.02 before
(+0.82 with the lever alone, +1.18 with the bias alone; seed 4, bench/HISTORY.md).

Pure and ROS-free; readings in base_link axes.
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

from quadrivio_description.frames import tilt_from_gravity
from quadrivio_description.vehicle import GRAVITY


def imu_lever(vehicle) -> tuple:
    """The IMU's position in base_link [m] (``vehicle.yaml``'s ``imu_link``; none: the origin)."""
    return tuple(vehicle.sensors["imu_link"].xyz) if "imu_link" in vehicle.sensors else (0.0, 0.0, 0.0)


class Attitude:
    def __init__(self, tau: float = 4.0, max_accel: float = 8.0, speed_timeout: float = 0.25,
                 max_bias: float = 0.05, lever: Sequence[float] = (0.0, 0.0, 0.0),
                 start_band: float = math.inf) -> None:
        self.lever = tuple(float(c) for c in lever)
        self.tau, self.max_accel, self.speed_timeout, self.max_bias = tau, max_accel, speed_timeout, max_bias
        self.start_band = start_band  # [1] the first sample used weighs 1 g within this fraction (the roscpp
        #                               guard's copy starts on any: inf)
        self.roll = self.pitch = 0.0
        self.bias_roll = self.bias_pitch = 0.0  # [rad/s] learnt from the pull, subtracted from the rates
        self.t: Optional[float] = None  # the newest IMU sample's time
        self.started = False
        self.speed: Optional[tuple] = None  # (t, v) newest wheel speed
        self.accel = 0.0  # [m/s^2] the wheel speed's newest slope
        self.accel_ok = False
        self.f_origin: Sequence[float] = (0.0, 0.0, 0.0)

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
        f = self.without_lever(f, w)
        self.f_origin = f  # the newest sample's specific force at base_link's origin (for other users)
        g = (f[0] - (self.accel if fresh else 0.0), f[1] - v * w[2], f[2])
        roll_g, pitch_g = tilt_from_gravity(g)
        if not self.started:
            # Start on a sample that weighs about 1 g (``start_band``): the first samples of a
            # vehicle dropped onto its wheels (the simulator's spawn) read 0.2 g, 15 deg off, and
            # tau carried that error for seconds (the slip test took it for a wheel slip)
            if abs(math.sqrt(g[0] * g[0] + g[1] * g[1] + g[2] * g[2]) / GRAVITY - 1.0) <= self.start_band:
                self.roll, self.pitch, self.started, self.t = roll_g, pitch_g, True, t
            return
        dt = t - self.t
        self.t = t
        sr, cr, tp = math.sin(self.roll), math.cos(self.roll), math.tan(self.pitch)
        self.roll += (w[0] + (w[1] * sr + w[2] * cr) * tp - self.bias_roll) * dt
        self.pitch += (w[1] * cr - w[2] * sr - self.bias_pitch) * dt
        if (fresh and self.accel_ok) or self.speed is None:
            k = min(1.0, dt / self.tau)
            e_roll, e_pitch = roll_g - self.roll, pitch_g - self.pitch
            self.roll += k * e_roll
            self.pitch += k * e_pitch
            ki = dt / (4.0 * self.tau * self.tau)
            mb = self.max_bias
            self.bias_roll = min(max(self.bias_roll - ki * e_roll, -mb), mb)
            self.bias_pitch = min(max(self.bias_pitch - ki * e_pitch, -mb), mb)

    def without_lever(self, f: Sequence[float], w: Sequence[float]):
        """The specific force at base_link's origin: an IMU ``lever`` [m] from it also feels
        the centripetal ``w x (w x r)``, whose mean is not zero on bumps."""
        rx, ry, rz = self.lever
        if rx == ry == rz == 0.0:
            return f
        wr = w[0] * rx + w[1] * ry + w[2] * rz
        ww = w[0] * w[0] + w[1] * w[1] + w[2] * w[2]
        return (f[0] - (w[0] * wr - rx * ww), f[1] - (w[1] * wr - ry * ww), f[2] - (w[2] * wr - rz * ww))

    def valid(self, now: float, timeout: float) -> bool:
        return self.t is not None and now - self.t <= timeout
