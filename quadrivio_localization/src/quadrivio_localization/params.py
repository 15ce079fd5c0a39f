"""The smoother's parameters (``config/localization.yaml``): noise, calibration priors, the
magnetometer's calibration, the GPS gate, and the node-independent options. Split from
:mod:`.smoother` so that tools and tests can read and validate them without GTSAM."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Tuple

import numpy as np

from quadrivio_config import param

from .gps_gate import GpsGateParams


@dataclass(frozen=True)
class NoiseParams:
    odometry_xy: float = param(0.01, lo=1e-5, hi=10.0, unit="m", doc="odometry position noise per interval")
    odometry_xy_per_m: float = param(0.03, lo=0.0, hi=1.0, unit="m/m", doc="odometry position noise per metre")
    odometry_theta: float = param(0.002, lo=1e-6, hi=1.0, unit="rad", doc="odometry heading noise per interval")
    odometry_theta_per_m: float = param(0.01, lo=0.0, hi=1.0, unit="rad/m", doc="odometry heading noise per metre")
    gyro_noise: float = param(2e-3, lo=1e-6, hi=1.0, unit="rad/s/sqrt(Hz)", doc="gyro white noise density (with model error)")
    gyro_bias_walk: float = param(1e-4, lo=1e-8, hi=1.0, unit="rad/s^2/sqrt(Hz)", doc="gyro bias random walk")
    gps_floor: float = param(0.02, lo=1e-4, hi=100.0, unit="m", doc="smallest GPS white-noise standard deviation")
    gps_drift: float = param(0.15, lo=0.0, hi=100.0, unit="m",
                             doc="stationary std of the receiver's drift (part of each fix's reported variance)")
    gps_drift_tau: float = param(120.0, lo=1.0, hi=1e5, unit="s", doc="correlation time of the receiver's drift")
    gps_default: float = param(3.0, lo=1e-3, hi=1000.0, unit="m", doc="GPS standard deviation when the fix has none")
    gps_huber: float = param(1.5, lo=0.1, hi=100.0, doc="Huber threshold of the GPS factors [sigma]")
    mag: float = param(1.5, lo=1e-3, hi=100.0, unit="uT",
                       doc="magnetometer model error of a slot's mean reading, horizontal (correlated over a slot)")
    mag_white: float = param(0.3, lo=0.0, hi=100.0, unit="uT", doc="magnetometer white noise per reading")
    mag_huber: float = param(2.0, lo=0.1, hi=100.0, doc="Huber threshold of the magnetometer factors [sigma]")
    no_odometry: Tuple[float, float, float] = param((3.0, 3.0, 0.5), unit="m, m, rad",
                                                    doc="weak motion prior for an interval without odometry")
    no_odometry_accel: float = param(3.0, lo=0.0, hi=100.0, unit="m/s^2",
                                     doc="without odometry the vehicle keeps its velocity, give or take this "
                                         "acceleration (0: no such factor)")
    imu_speed_sd: float = param(0.15, lo=1e-3, hi=100.0, unit="m/s",
                                doc="while the wheel lies (locked, slipping, dead), the IMU's speed since the "
                                    "fault's onset: its sd at the onset (the wheel's speed then)...")
    imu_speed_sd_per_s: float = param(0.3, lo=0.0, hi=100.0, unit="m/s^2",
                                      doc="...growing by this per second (a pitch 1 deg off is 0.17 m/s^2)")
    kinematic_walk: Tuple[float, float, float] = param((2e-4, 2e-4, 4e-4), unit="1/sqrt(s), rad/sqrt(s), 1/sqrt(s)",
                                                       doc="random walk of k_v, h_0, k_d")
    mag_walk: Tuple[float, float, float, float, float] = param((0.02, 0.02, 5e-4, 5e-4, 5e-4),
                                                               unit="uT/sqrt(s) (x2), 1/sqrt(s) (x3)",
                                                               doc="random walk of the magnetometer calibration")


@dataclass(frozen=True)
class Prior:
    mean: float = param(doc="prior mean")
    sigma: float = param(lo=1e-9, hi=1e9, doc="prior standard deviation")


@dataclass(frozen=True)
class MagCalibration:
    """What is known of the magnetometer before the run: a calibration from recorded data
    (``rosrun quadrivio_localization calibrate_mag``) or, without one, wide priors. With an
    unknown hard iron of sigma ``s`` against a horizontal field ``h``, north is only known
    to about ``s / h`` rad until the vehicle moves: calibrate the magnetometer once."""
    hard_iron: Tuple[float, float] = param((0.0, 0.0), unit="uT", doc="o_x, o_y")
    hard_iron_sigma: float = param(15.0, lo=1e-6, hi=1e3, unit="uT", doc="standard deviation of o_x and o_y")
    soft_iron: Tuple[float, float, float] = param((1.0, 1.0, 0.0), unit="1", doc="s_xx, s_yy, s_xy")
    soft_iron_sigma: Tuple[float, float, float] = param((0.2, 0.2, 0.1), unit="1", doc="their standard deviations")
    source: str = param("uncalibrated", doc="where the calibration comes from (bag, date): reported, not used")

    def vectors(self) -> Tuple[np.ndarray, np.ndarray]:
        mean = np.array(list(self.hard_iron) + list(self.soft_iron), float)
        sigma = np.array([self.hard_iron_sigma] * 2 + list(self.soft_iron_sigma), float)
        return mean, sigma


@dataclass(frozen=True)
class CalibrationPriors:
    wheel_speed_scale: Prior = param(Prior(1.0, 0.05), doc="k_v [1]")
    handlebar_offset: Prior = param(Prior(0.0, 0.05), doc="h_0 [rad]")
    steering_gain: Prior = param(Prior(1.0, 0.1), doc="k_d [1]")
    gyro_bias: Prior = param(Prior(0.0, 0.01), doc="[rad/s]")
    magnetometer: MagCalibration = param(MagCalibration(), doc="hard and soft iron of the levelled magnetometer")


@dataclass(frozen=True)
class LocalizerParams:
    rate: float = param(20.0, lo=1.0, hi=200.0, unit="Hz", doc="keyframe and output rate")
    lag: float = param(3.0, lo=0.2, hi=60.0, unit="s", doc="smoother window (keyframes leave it a second at a time)")
    max_wait: float = param(0.25, lo=0.0, hi=5.0, unit="s",
                            doc="create a keyframe this long after its time even if a sensor has not covered it")
    odometry_hold: float = param(0.2, lo=0.0, hi=5.0, unit="s",
                                 doc="a wheel speed and handlebar (or gyro) sample stands for at most this long "
                                     "after its stamp; beyond it, or across a gap in the samples, an interval has no "
                                     "odometry (no gyro): a silent PLC link is not a vehicle driving on at its last "
                                     "speed, before or after it comes back")
    use_gps: bool = param(True)
    use_mag: bool = param(True)
    use_gyro: bool = param(True)
    use_odometry: bool = param(True)
    wheel_check_rate: float = param(0.05, lo=0.0, hi=10.0, unit="rad/s",
                                    doc="a wheel speed of 0 while the gyro's yaw rate is above this...")
    wheel_check_time: float = param(0.3, lo=0.0, hi=60.0, unit="s",
                                    doc="...for this long is a dead wheel-speed channel: odometry ignored (0: never)")
    wheel_slip_threshold: float = param(0.8, lo=0.0, hi=10.0, unit="m/s",
                                        doc="wheels that report this much more (or less) speed change than the IMU "
                                            "over wheel_slip_window, or more speed than a steady stream of fixes, "
                                            "slip: odometry ignored while it lasts (0: never)")
    wheel_slip_window: float = param(0.5, lo=0.05, hi=10.0, unit="s", doc="the IMU test's window")
    wheel_slip_sigmas: float = param(4.0, lo=0.0, hi=100.0,
                                     doc="...and at least this many of that difference's RMS over the last 10 s "
                                         "without a slip (rough ground: the wheel climbs every bump; 0: the "
                                         "threshold alone)")
    wheel_lock_decel: float = param(12.0, lo=0.0, hi=1000.0, unit="m/s^2",
                                    doc="a wheel speed that drops faster than this is a locked wheel, not the vehicle: "
                                        "odometry ignored until it reads motion again or the vehicle would have "
                                        "stopped at no_odometry_accel (0: never)")
    mag_rate: float = param(2.0, lo=0.1, hi=50.0, unit="Hz", doc="magnetometer factors per second (readings averaged)")
    calibrate: bool = param(True, doc="estimate the calibration online (false: hold the priors' means)")
    calibration_every: int = param(5, lo=1, hi=100,
                                   doc="keyframes per calibration state (gyro bias, odometry, magnetometer): they "
                                       "drift over minutes, so one state every few keyframes holds them as well "
                                       "with fewer variables in the window; the keyframes between use the last one")
    initial_heading_sigma: float = param(3.0, lo=1e-3, hi=4.0, unit="rad",
                                         doc="prior on the first heading (weak: the magnetometer factors and their "
                                             "calibration priors already say how well north is known)")
    tilt_tau: float = param(1.0, lo=0.0, hi=100.0, unit="s", doc="low-pass of roll/pitch from the accelerometer")
    altitude_tau: float = param(2.0, lo=0.0, hi=100.0, unit="s", doc="low-pass of the altitude from GPS")
    noise: NoiseParams = param(NoiseParams())
    gps_gate: GpsGateParams = param(GpsGateParams(), doc="which GPS fixes are believed (outliers, multipath)")
    priors: CalibrationPriors = param(CalibrationPriors())
