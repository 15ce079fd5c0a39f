"""Fixed-lag smoother for the Quadrivio ATV with online self-calibration (paper section 2.2).

Like ROAMFREE on the real vehicle, the smoother fuses vehicle kinematics (rear wheel
speed and handlebar angle), the gyroscope, the GPS and the magnetometer, and
estimates the calibration of its own measurement models while it goes: wheel speed
scale, handlebar offset, steering gain, gyro bias (a random walk), and the
magnetometer's hard and soft iron.

Keyframes ``X_k`` (gtsam.Pose2 of base_link in map) lie on a fixed grid of
``1 / rate`` s. A keyframe is created once the odometry and the IMU cover its interval
(or ``max_wait`` s have passed: a silent sensor does not stop the estimate), so late
data is waited for briefly; GPS fixes, which arrive about 80 ms after their stamp, are
attached to the keyframe of their measurement time when they arrive. The graph is
solved by iSAM2 over a fixed-lag window (``lag`` s, :mod:`.window`, which keeps the
chain in time order so that an update re-eliminates its newest part only; GTSAM's
IncrementalFixedLagSmoother re-eliminated the whole window at every update, 12 ms of
every 50). As in ROAMFREE, the calibration
parameters are slowly varying processes: one value per keyframe, linked by a tight
random walk, so the graph stays a chain and an update only touches its newest part.

Magnetometer: one factor per ``1 / mag_rate`` s (2 Hz) of averaged readings with a
model-error sigma, and one per stop while the vehicle stands still. At rest the
heading and the hard iron are observable only together (as far as the calibration
priors allow: 15 uT of unknown hard iron against a 24 uT horizontal field is +-35
degrees of heading), and 20 Hz of factors claiming independent errors, once
marginalised at slightly different linearisation points, dragged the heading by 45
degrees in 5 s while the reported sigma shrank to 9 degrees. The odometry factor's
position error is in map axes for the same reason (see factors.odometry_factor).

Outliers and multipath: GPS factors have a Huber kernel, and :mod:`.gps_gate` decides
which fixes are used at all, by tests scaled by the fix's reported covariance and status
and by the estimate's own covariance (nothing in metres); every fix not used is counted
by reason. Every factor's model is in :mod:`quadrivio_localization.factors`.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Deque, Dict, List, Optional, Tuple

import gtsam
import numpy as np

from quadrivio_description.attitude import imu_lever
from quadrivio_description.kinematics import max_delta
from quadrivio_description.site import SiteParams
from quadrivio_description.vehicle import VehicleParams

from . import factors
from .gps_gate import NO_FIX, NOT_FINITE, TOO_OLD, GpsGate
from .params import CalibrationPriors, LocalizerParams, MagCalibration, NoiseParams, Prior

# The parameters moved to .params; importing them from here keeps working.
__all__ = ["Localizer", "Estimate", "Counters", "CALIBRATION_NAMES", "CalibrationPriors", "LocalizerParams",
           "MagCalibration", "NoiseParams", "Prior"]
from .buffers import SampleBuffer
from .leveling import Leveller, lowpass
from .wheel_lock import DeadWheel, WheelLock
from .wheel_slip import SlipParams, WheelSlip
from .window import FixedLagWindow

X = gtsam.symbol_shorthand.X  # poses
B = gtsam.symbol_shorthand.B  # gyro bias
K = gtsam.symbol_shorthand.K  # kinematic calibration (k_v, h_0, k_d)
M = gtsam.symbol_shorthand.M  # magnetometer calibration (o_x, o_y, s_x, s_y, s_xy), field in uT
G = gtsam.symbol_shorthand.G  # GPS receiver drift (east, north) [m]
# B, K, M and G have one variable per keyframe, linked by random walks: the graph stays a
# chain (constant variables tied to every factor would make iSAM2 relinearize and
# re-eliminate the whole window at each update), and the calibration may drift slowly.
UT = 1e6  # tesla -> microtesla
# iSAM2 relinearises a variable when its update exceeds these (per component). The factors
# are linear in the gyro bias, the magnetometer calibration and the GPS drift: only the
# poses (through the heading) and the kinematic calibration (through the arc) need it.
# A relinearised variable re-eliminates the window from it to the newest keyframe: the
# slowest updates (p99) were those where a GPS fix moved the last second of poses by a few
# centimetres each and all of them were relinearised. A between-factor of two poses does
# not change with a translation of both (only the heading rotates it), so the position
# threshold is loose and the heading's tight; the kinematic calibration's is 0.005. On
# seed 0/1 of consumer, urban_multipath, uncalibrated, dead_wheel, rtk, long_outage and
# gps_latency: update CPU p99 3.5-4.8 -> 3.2-3.8 ms, RMSE within 0.001 m, heading within
# 0.01 deg (x 0.02 m, k 0.002 before). Then the heading's 0.005 rad set off 31 of the 32
# slowest updates of uncalibrated (seed 0): a fix turning the last second of poses by a
# third of a degree relinearised ~100 variables. At 0.02 rad (GTSAM's default is 0.1) on
# seeds 0-2 of uncalibrated, consumer and rtk: RMSE and heading RMSE within 0.0004 m and
# 0.0004 deg, calibration within 0.002 %; update CPU p99 of uncalibrated 4.2-4.5 ->
# 3.4-4.2 ms (two runs at a time on 2 cores).
RELINEARIZE = gtsam.ISAM2ThresholdMap()
for _char, _limit in (("x", [0.2, 0.2, 0.02]), ("k", [0.005, 0.005, 0.005]), ("b", [1e9]), ("m", [0.5, 0.5, 0.005, 0.005, 0.005]),
                      ("g", [1e9] * 2)):
    RELINEARIZE.insert((_char, np.array(_limit, float)))
CALIBRATION_NAMES = ("wheel_speed_scale", "handlebar_offset", "steering_gain", "gyro_bias", "mag_hard_iron_x",
                     "mag_hard_iron_y", "mag_soft_iron_xx", "mag_soft_iron_yy", "mag_soft_iron_xy")


@dataclass
class Estimate:
    stamp: float  # [s] time of the newest keyframe
    x: float  # [m] base_link in map
    y: float
    theta: float  # [rad]
    z: float  # [m] from the GPS altitude
    roll: float  # [rad] from the accelerometer
    pitch: float
    covariance: np.ndarray  # 3 x 3 of (x, y, theta) in map axes
    speed: float  # [m/s] calibrated rear axle speed
    yaw_rate: float  # [rad/s] bias-corrected, about the vertical
    calibration: Dict[str, float]


@dataclass
class Counters:
    keyframes: int = 0
    gps_used: int = 0  # (the fixes not used, by reason: Localizer.gate.counts)
    mag_used: int = 0
    mag_skipped_at_rest: int = 0
    mag_late: int = 0  # readings of a slot already closed (the magnetometer later than max_wait)
    intervals_without_odometry: int = 0
    intervals_without_gyro: int = 0
    intervals_wheel_rejected: int = 0  # the wheel read 0 while the vehicle moved (Localizer.faults)
    intervals_wheel_locked: int = 0  # the wheel speed dropped faster than the vehicle can brake
    intervals_imu_speed: int = 0  # of those without odometry: the IMU's speed since the fault's onset used
    intervals_wheel_slip: int = 0  # the wheels reported motion the IMU or the GPS denied (wheel_slip.py)
    out_of_order: int = 0
    bad_input: int = 0
    update_time: float = 0.0  # [s] wall time of the last smoother update (set by the caller)


def _finite(*values) -> bool:
    return all(math.isfinite(v) for v in values)


class Localizer:
    """Feed stamped sensor data with ``add_*`` in arrival order, call :meth:`update` at ``rate``."""

    REST_SPEED = 0.05  # [m/s] wheel speed below which the vehicle stands still

    def __init__(self, p: LocalizerParams, vehicle: VehicleParams, site: SiteParams) -> None:
        self.p = p
        self.v = vehicle
        self.frame = site.local_frame()
        h = site.magnetic_field.enu()
        self.h_en = (h[0] * UT, h[1] * UT)
        self.lever = tuple(vehicle.sensors["gps_link"].xyz[:2])
        self.lever_z = vehicle.sensors["gps_link"].xyz[2]
        self.leveller = Leveller(vehicle, p.tilt_tau, p.max_wait)
        self.dt = 1.0 / p.rate
        self.max_delta = max_delta(vehicle)  # [rad] the wheels turn no further, whatever the calibration
        self.states: SampleBuffer[Tuple[float, float]] = SampleBuffer()  # speed [m/s], handlebar [rad]
        self.gyro: SampleBuffer[float] = SampleBuffer()  # vertical rate [rad/s]
        self.mags: Deque[Tuple[float, float, float]] = deque(maxlen=5000)  # t, levelled m_x, m_y [uT]
        self.mag_newest_t = -math.inf  # stamp of the newest reading received
        self.mag_closed = -math.inf  # index of the last magnetometer slot made a factor
        self.gps_pending: List[Tuple[float, np.ndarray, float, float, int]] = []  # t, enu, white var e, n, status
        self.gate = GpsGate(p.gps_gate)
        self.decided: Deque[Tuple[float, np.ndarray, int, np.ndarray]] = deque(maxlen=64)  # t, fix, k, R
        self.no_odometry_t = -math.inf  # end of the newest interval without odometry
        self.no_odometry_from_k = 0  # and the start of its stretch
        self.imu_anchor: Optional[Tuple[float, float]] = None  # (t, speed) at the wheel fault's onset
        self.wheel_lock = WheelLock(p.wheel_lock_decel, p.noise.no_odometry_accel, self.REST_SPEED, self.dt)
        self.slip = WheelSlip(SlipParams(window=p.wheel_slip_window, threshold=p.wheel_slip_threshold,
                                         sigmas=p.wheel_slip_sigmas),
                              lever=imu_lever(vehicle)) if p.wheel_slip_threshold > 0.0 else None
        self.prev_fix: Optional[Tuple[float, np.ndarray, int, np.ndarray]] = None  # t, fix, keyframe, R
        self.dead_wheel = DeadWheel(p.wheel_check_rate, p.wheel_check_time, self.REST_SPEED, self.dt)
        self.events: List[str] = []  # for the node's log
        self.z: Optional[float] = None
        self.z_t: Optional[float] = None
        self.k: Optional[int] = None  # newest keyframe index
        self.k_origin = 0  # the first keyframe's (set by _initialize)
        self.oldest_k: Optional[int] = None
        self.smoother: Optional[FixedLagWindow] = None
        self.result = gtsam.Values()
        self.counters = Counters()
        self.cov = np.diag([1e4, 1e4, 10.0])
        self.mag_at_rest = False  # a magnetometer factor already stands for the current stop
        self.latest_t = -math.inf  # newest sensor time seen
        self.latest_speed = 0.0  # [m/s] calibrated speed of the newest interval
        self.latest_rate = 0.0  # [rad/s] bias-corrected yaw rate of the newest interval

    # ------------------------------------------------------------------ input
    def add_vehicle_state(self, t: float, speed: float, handlebar: float) -> None:
        if not _finite(t, speed, handlebar):
            self.counters.bad_input += 1
            return
        if not self.states.append(t, (speed, handlebar)):
            self.counters.out_of_order += 1
            return
        self.leveller.add_speed(t, speed)
        if self.slip is not None:
            self.slip.add_speed(t, speed)
        self.latest_t = max(self.latest_t, t)

    def add_imu(self, t: float, f: Tuple[float, float, float], w: Tuple[float, float, float]) -> None:
        if not _finite(t, *f, *w):
            self.counters.bad_input += 1
            return
        if self.gyro and t < self.gyro.last_t:
            self.counters.out_of_order += 1
            return
        self.gyro.append(t, self.leveller.add_imu(t, f, w))
        if self.slip is not None:
            self.slip.add_imu(t, *self.leveller.body)
        self.latest_t = max(self.latest_t, t)

    def add_mag(self, t: float, m: Tuple[float, float, float]) -> None:
        if not _finite(t, *m):
            self.counters.bad_input += 1
            return
        mx, my = self.leveller.level_mag(m)
        self.mags.append((t, mx * UT, my * UT))
        self.mag_newest_t = max(self.mag_newest_t, t)

    def add_gps(self, t: float, lat: float, lon: float, alt: float, var_e: float, var_n: float, status: int) -> None:
        if status < 0:
            self.gate.skip(NO_FIX, t)
            return
        if not _finite(t, lat, lon, alt):
            self.counters.bad_input += 1
            self.gate.skip(NOT_FINITE, t)
            return
        enu = np.asarray(self.frame.lla_to_enu(lat, lon, alt))
        self.z = lowpass(self.z, float(enu[2]) - self.lever_z, self.z_t, t, self.p.altitude_tau)
        self.z_t = t
        # The reported variance, or gps_default without one, is white noise plus the drift,
        # which is a state: the factor keeps the white part, floored by what the fix's
        # status can deliver (a plain FIX claiming centimetres is not believed).
        default = self.p.noise.gps_default ** 2
        floor = max(self.p.noise.gps_floor ** 2, self.p.gps_gate.status_floor(status))
        d2 = self.p.noise.gps_drift ** 2
        ve = var_e if _finite(var_e) and var_e > 0 else default
        vn = var_n if _finite(var_n) and var_n > 0 else default
        if self.slip is not None:
            self.slip.add_fix(t, float(enu[0]), float(enu[1]), max(ve, vn, floor))
        self.gps_pending.append((t, enu[:2], max(ve - d2, floor), max(vn - d2, floor), int(status)))

    # ---------------------------------------------------------------- helpers
    def _t(self, k: int) -> float:
        return k * self.dt

    def _samples(self, t0: float, t1: float) -> List[Tuple[float, float, float]]:
        """Piecewise-constant ``(dt, speed, handlebar)`` over ``[t0, t1]`` from the states;
        none when a state would stand for more than ``odometry_hold`` anywhere in it: past
        the newest state, or across a gap (states that stopped for seconds and came back:
        the state before the gap must not drive the keyframes made when they return)."""
        pieces = self.states.pieces(t0, t1, max_hold=self.p.odometry_hold)
        return [(dt, v, h) for dt, (v, h) in pieces]

    def _gyro_integral(self, t0: float, t1: float) -> Optional[float]:
        if not self.gyro or self.gyro.last_t < t1 - 0.5 * self.dt:
            return None
        return self.gyro.integral(t0, t1, max_hold=self.p.odometry_hold)  # a gap: no gyro over it

    def _covered(self, t1: float, now: float) -> bool:
        """Whether the odometry and the gyro have data up to ``t1`` (or waiting is over)."""
        if now - t1 >= self.p.max_wait:
            return True
        ok_states = not self.p.use_odometry or (self.states and self.states.last_t >= t1 - 1e-9)
        ok_gyro = not self.p.use_gyro or (self.gyro and self.gyro.last_t >= t1 - 1e-9)
        return bool(ok_states and ok_gyro)

    def _c(self, k: int) -> int:
        """The keyframe of the calibration state that keyframe ``k`` uses (the last at or before it)."""
        n = self.p.calibration_every
        return k if n == 1 else self.k_origin + n * ((k - self.k_origin) // n)

    def _vector(self, key: int, values: gtsam.Values) -> np.ndarray:
        return values.atVector(key) if values.exists(key) else self.result.atVector(key)

    def _has(self, key: int, values: gtsam.Values) -> bool:
        return values.exists(key) or self.result.exists(key)

    def _prior_vector(self, priors) -> Tuple[np.ndarray, np.ndarray]:
        return np.array([p.mean for p in priors]), np.array([p.sigma for p in priors])

    # ----------------------------------------------------------- initialising
    def _initialize(self, now: float) -> bool:
        """Start the graph at the first grid time after the first GPS fix."""
        if not self.gps_pending or (self.p.use_mag and not self.mags):
            return False
        t_gps, z, ve, vn, _ = self.gps_pending[0]
        pr = self.p.priors
        kin_mean, kin_sigma = self._prior_vector((pr.wheel_speed_scale, pr.handlebar_offset, pr.steering_gain))
        mag_mean, mag_sigma = pr.magnetometer.vectors()
        if not self.p.calibrate:  # calibration held at the priors' means (see _add_keyframe)
            kin_sigma, mag_sigma = kin_sigma * 1e-3, mag_sigma * 1e-3
        self.held = (kin_mean, kin_sigma, mag_mean, mag_sigma)
        self.k = self.oldest_k = int(math.ceil(t_gps / self.dt - 1e-9))
        self.k_origin = self.k  # calibration states at k_origin + n * calibration_every
        m_avg = None
        if self.p.use_mag:
            # The readings so far (up to half a mag slot back) make the first keyframe's factor
            # and its heading guess; later ones go to the regular slots.
            recent = [m for m in self.mags if abs(m[0] - t_gps) < 0.5 / self.p.mag_rate] or [self.mags[-1]]
            m_avg = np.mean([(m[1], m[2]) for m in recent], axis=0)
            n_recent = len(recent)
            theta0 = factors.mag_heading(m_avg, mag_mean, self.h_en)
            t_first = self._t(self.k)
            while self.mags and self.mags[0][0] <= t_first:
                self.mags.popleft()
        else:
            theta0 = 0.0
        R = np.array([[math.cos(theta0), -math.sin(theta0)], [math.sin(theta0), math.cos(theta0)]])
        xy = z - R @ np.asarray(self.lever)
        pose0 = gtsam.Pose2(float(xy[0]), float(xy[1]), theta0)
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE)
        params.relinearizeSkip = 1
        # Reuse the slots of factors removed by marginalisation: else iSAM2's factor list
        # grows by a dozen empty slots per keyframe, forever (450,000 in an hour).
        params.findUnusedFactorSlots = True
        self.smoother = FixedLagWindow(self.p.lag, params)
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        heading_sigma = self.p.initial_heading_sigma if self.p.use_mag else math.pi
        pos_sigma = math.sqrt(max(ve, vn) + self.p.noise.gps_drift ** 2) + 0.5
        graph.add(gtsam.PriorFactorPose2(X(self.k), pose0,
                                         gtsam.noiseModel.Diagonal.Sigmas(np.array([pos_sigma, pos_sigma, heading_sigma]))))
        graph.add(gtsam.PriorFactorVector(B(self.k), np.array([pr.gyro_bias.mean]),
                                          gtsam.noiseModel.Diagonal.Sigmas(np.array([pr.gyro_bias.sigma]))))
        graph.add(gtsam.PriorFactorVector(K(self.k), kin_mean, gtsam.noiseModel.Diagonal.Sigmas(kin_sigma)))
        graph.add(gtsam.PriorFactorVector(M(self.k), mag_mean, gtsam.noiseModel.Diagonal.Sigmas(mag_sigma)))
        values.insert(X(self.k), pose0)
        values.insert(B(self.k), np.array([pr.gyro_bias.mean]))
        values.insert(K(self.k), kin_mean)
        values.insert(M(self.k), mag_mean)
        drift = max(self.p.noise.gps_drift, 1e-3)
        graph.add(gtsam.PriorFactorVector(G(self.k), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, drift)))
        values.insert(G(self.k), np.zeros(2))
        if m_avg is not None:
            graph.add(factors.mag_factor(self._mag_noise(n_recent), X(self.k), M(self.k), m_avg, self.h_en))
            self.counters.mag_used += 1
        t = self._t(self.k)
        stamps = {X(self.k): t, B(self.k): t, K(self.k): t, M(self.k): t, G(self.k): t}
        self.kin_walk = np.asarray(self.p.noise.kinematic_walk) * math.sqrt(self.dt)
        self.mag_walk = np.asarray(self.p.noise.mag_walk) * math.sqrt(self.dt)
        # Gauss-Markov drift of stationary std s and correlation time tau: g1 = phi g0 + w,
        # phi = exp(-dt / tau), w of std s sqrt(1 - phi^2). Mean-reverting: a random walk
        # of the same increments lets a drift of a metre wander off unanchored in minutes.
        self.gps_phi = math.exp(-self.dt / self.p.noise.gps_drift_tau)
        self.gps_walk = np.full(2, drift * math.sqrt(1.0 - self.gps_phi ** 2))
        # the noise models every keyframe uses, made once: the calibration states walk over
        # calibration_every keyframes
        Sigmas = gtsam.noiseModel.Diagonal.Sigmas
        span = math.sqrt(self.p.calibration_every)
        self.walk_noise = {B: Sigmas(np.array([self.p.noise.gyro_bias_walk * math.sqrt(self.dt)]) * span),
                           K: Sigmas(self.kin_walk * span), M: Sigmas(self.mag_walk * span), G: Sigmas(self.gps_walk)}
        self.gyro_noise = gtsam.noiseModel.Isotropic.Sigma(1, self.p.noise.gyro_noise * math.sqrt(self.dt))
        self.smoother.update(graph, values, stamps)
        self.result = self.smoother.solution()
        return True

    # ---------------------------------------------------------------- updating
    def update(self, now: float) -> Optional[Estimate]:
        """Add every keyframe whose data is in (up to ``now``), solve, return the newest estimate."""
        if self.smoother is None:
            if not self._initialize(now):
                self._trim(now)
                return None
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        created = 0
        while self._t(self.k + 1) <= now + 1e-9 and self._covered(self._t(self.k + 1), now):
            self._add_keyframe(graph, values, stamps)
            created += 1
        if created == 0:
            # Fixes and magnetometer slots wait for the next keyframe: an update of a few
            # keys only would leave the window's elimination order to COLAMD (see .window).
            return self._estimate()
        self._add_gps(graph, values)
        self._add_mags(graph, values, now)
        t_new = self._t(self.k)
        self.smoother.update(graph, values, stamps)
        self.result = self.smoother.solution()
        if self.no_odometry_t >= t_new - 1e-9:
            # Without odometry the speed is the estimate's own motion over the last second
            # without it (the constant-velocity factor and the fixes), not the last wheel
            # speed: that one said 1.4 m/s on /localization/odom for the 9.6 s a frozen
            # client's vehicle stood braked.
            k0 = max(self.no_odometry_from_k, self.k - int(round(1.0 / self.dt)), self.oldest_k)
            if k0 < self.k and self.result.exists(X(k0)):
                step = self.result.atPose2(X(k0)).between(self.result.atPose2(X(self.k)))
                self.latest_speed = step.x() / ((self.k - k0) * self.dt)
        try:
            self.cov = np.asarray(self.smoother.marginalCovariance(X(self.k)))
        except RuntimeError:
            pass
        self.oldest_k = max(self.oldest_k, int(math.ceil((t_new - self.p.lag) / self.dt)) + 1)
        self._trim(now)
        return self._estimate()

    def _add_keyframe(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: Dict) -> None:
        k0, k1 = self.k, self.k + 1
        t0, t1 = self._t(k0), self._t(k1)
        nz = self.p.noise
        prev = self._pose(k0, values)
        c0 = self._c(k0)  # the calibration state these intervals use
        prev_b, kin, mag = self._vector(B(c0), values), self._vector(K(c0), values), self._vector(M(c0), values)
        drift = self._vector(G(k0), values)
        samples = self._samples(t0, t1) if self.p.use_odometry else []
        dth_gyro = self._gyro_integral(t0, t1) if self.p.use_gyro else None
        slipping = self._wheel_slip(t1)
        if samples and slipping:
            samples = []  # the wheels turn, the vehicle does not (or not as fast)
            self.counters.intervals_wheel_slip += 1
        elif samples and self._wheel_dead(t1, samples, dth_gyro, float(prev_b[0])):
            samples = []  # a wheel that reads 0 while the vehicle turns says nothing true
            self.counters.intervals_wheel_rejected += 1
        elif samples and self._wheel_locked(t0, t1):
            samples = []  # nor one that stopped faster than the vehicle can
            self.counters.intervals_wheel_locked += 1
        if samples:
            span = sum(dt for dt, _, _ in samples)
            speed = sum(dt * v for dt, v, _ in samples) / span
            handlebar = sum(dt * h for dt, _, h in samples) / span
            (dx, dy, dth), _ = factors.arc(span, speed, handlebar, kin, self.v.wheelbase, self.v.steering.ratio,
                                     self.max_delta)
            dist = abs(speed) * span * kin[0]
            sxy = math.hypot(nz.odometry_xy, nz.odometry_xy_per_m * dist)
            sth = math.hypot(nz.odometry_theta, nz.odometry_theta_per_m * dist)
            graph.add(factors.odometry_factor(gtsam.noiseModel.Diagonal.Sigmas(np.array([sxy, sxy, sth])), X(k0), X(k1),
                                        K(c0), span, speed, handlebar, self.v.wheelbase, self.v.steering.ratio,
                                        self.max_delta))
            guess = prev.compose(gtsam.Pose2(dx, dy, dth))
            self.latest_speed = kin[0] * samples[-1][1]
        else:
            self.counters.intervals_without_odometry += 1
            if self.no_odometry_t < t0 - 1e-9:
                self.no_odometry_from_k = k0  # the first keyframe of this stretch without odometry
                self.imu_anchor = self._fault_onset(float(kin[0]))
            self.no_odometry_t = t1
            step, sigmas = gtsam.Pose2(), np.array(nz.no_odometry)
            ahead = self._imu_advance(t0, t1)
            if ahead is not None:
                # The wheel lies (locked, slipping, dead): the IMU says how fast the body went
                # since the fault began (a lock is a braking vehicle, a dead channel one that
                # drives on: the first wheel reading after the onset cannot tell them apart)
                step, sigmas[0] = gtsam.Pose2(ahead[0], 0.0, 0.0), ahead[1]
                self.counters.intervals_imu_speed += 1
            graph.add(gtsam.BetweenFactorPose2(X(k0), X(k1), step, gtsam.noiseModel.Diagonal.Sigmas(sigmas)))
            guess = prev
            before = self._pose(k0 - 1, values) if k0 - 1 >= self.oldest_k else None
            if before is not None and nz.no_odometry_accel > 0.0:
                # Neither the wheel nor the handlebar: the vehicle keeps its motion, give or
                # take a random acceleration (a braked vehicle stops within the GPS's reach).
                sigma = nz.no_odometry_accel * self.dt * self.dt
                graph.add(factors.constant_velocity_factor(gtsam.noiseModel.Isotropic.Sigma(2, sigma),
                                                     X(k0 - 1), X(k0), X(k1)))
                guess = prev.compose(before.between(prev))
        if dth_gyro is not None:
            graph.add(factors.gyro_factor(self.gyro_noise, X(k0), X(k1), B(c0), dth_gyro, self.dt))
            self.latest_rate = dth_gyro / self.dt - float(prev_b[0])
        else:
            self.counters.intervals_without_gyro += 1
        calibration_state = self._c(k1) == k1  # a new calibration state at k1, walked from c0's
        for key, value in ((B, prev_b), (K, kin), (M, mag), (G, drift)):
            if key is not G and not calibration_state:
                continue
            if key is G:
                graph.add(factors.gauss_markov_factor(self.walk_noise[G], G(k0), G(k1), self.gps_phi))
                value = self.gps_phi * value
            elif key is B or self.p.calibrate:
                graph.add(gtsam.BetweenFactorVector(key(c0), key(k1), np.zeros(len(value)), self.walk_noise[key]))
            else:  # held: a tight prior on each copy (a chain of tight walks would be ill-conditioned)
                mean, sigma = (self.held[0], self.held[1]) if key is K else (self.held[2], self.held[3])
                graph.add(gtsam.PriorFactorVector(key(k1), mean, gtsam.noiseModel.Diagonal.Sigmas(sigma)))
            values.insert(key(k1), value)
            stamps[key(k1)] = t1
        values.insert(X(k1), guess)
        stamps[X(k1)] = t1
        self.k = k1
        self.counters.keyframes += 1

    def _wheel_dead(self, t: float, samples, dth_gyro: Optional[float], bias: float) -> bool:
        """Whether the wheel-speed channel reads 0 while the vehicle moves (:class:`.DeadWheel`);
        named in :meth:`faults`."""
        rate = None if dth_gyro is None else dth_gyro / self.dt - bias
        lock = self.wheel_lock
        lock_until = lock.until if lock.since is not None and lock.confirmed else None
        dead, began, events = self.dead_wheel.update(t, max(abs(v) for _, v, _ in samples), rate, lock_until)
        self.events.extend(events)
        if began:
            # The last wheel_check_time s of odometry said "standing" and the estimate believed
            # it, covariance included: the gate must not judge the fixes by it. A burst that
            # began before the fault did (before a locked wheel that preceded it, too) is no
            # error of the estimate's and stays out (on rough ground at 3 m/s a 3.2 m burst
            # 0.4 s before a wheel locked and read 0 went in untested: the estimate rode the
            # burst 3.5 m off, held out the true fixes when it ended, and stopped the
            # vehicle for a bump it placed on the path).
            self.gate.unsettle(keep_burst_before=self._trusted_until(self._dead_onset(), "dead"))
        return dead

    def _trusted_until(self, onset: float, found: str) -> float:
        """Until when the estimate was trusted, for the wheel fault just ``found`` ("dead",
        "slip") that began at ``onset`` at the earliest: if another wheel fault is going on,
        this one is part of its episode (a lock that turns into a dead channel, a dead channel
        whose return reads as a spin-up), which began at the earliest of their onsets; else
        ``onset``."""
        going_on = []
        if self.dead_wheel.since is not None and found != "dead":
            going_on.append(self._dead_onset())
        if self.wheel_lock.since is not None:
            going_on.append(self.wheel_lock.drop[0])
        if self.slip is not None and self.slip.since is not None and found != "slip":
            going_on.append(self._slip_onset())
        return min(going_on) if going_on else onset

    def _dead_onset(self) -> float:
        """The earliest start of the dead wheel channel going on (its check's time before it was found)."""
        return self.dead_wheel.since - self.dead_wheel.check_time - self.dt

    def _slip_onset(self) -> float:
        """The earliest start of the slip going on (its tests' windows before it was found)."""
        return self.slip.since - max(self.slip.p.window, self.slip.p.gps_window)

    def _wheel_locked(self, t0: float, t1: float) -> bool:
        """Whether the wheel is locked over ``[t0, t1]`` (:mod:`.wheel_lock`); meanwhile the
        interval has no odometry (the IMU's speed since the drop, :meth:`_imu_advance`; the
        GPS says where it went)."""
        locked, events = self.wheel_lock.update(
            [(t, v) for t, (v, _) in self.states.stamped(t0 - 2.0 * self.dt, t1)], t0)
        self.events.extend(events)
        return locked

    def _fault_onset(self, k_v: float) -> Optional[Tuple[float, float]]:
        """When the wheel's fault that stops the odometry now began, and the vehicle's speed
        then [m/s] (the wheel's, calibrated): the IMU's speed starts there. None without a
        fault the wheel's own readings date (a silent vehicle state)."""
        if self.slip is None:
            return None
        if self.slip.since is not None:
            ta = self.slip.since - self.slip.p.window
        elif self.wheel_lock.since is not None:
            ta = self.wheel_lock.drop[0]
        elif self.dead_wheel.since is not None:
            ta = self._dead_onset()
        else:
            return None
        v = self.slip.speed_at(ta)
        return None if v is None else (ta, k_v * v)

    def _imu_advance(self, t0: float, t1: float) -> Optional[Tuple[float, float]]:
        """The body's forward advance over ``[t0, t1]`` [m] from the IMU's speed since the
        fault's onset, and its sd [m]; None without an onset or past the IMU's horizon."""
        a = self.imu_anchor
        if a is None or self.slip is None or t1 - a[0] > self.slip.p.imu_horizon:
            return None
        ta, va = a
        v = []
        for t in (t0, t1):
            dv = self.slip.body_change(ta, t)
            if dv is None:
                return None
            # a vehicle that brakes to a standstill does not reverse
            v.append(max(va + dv, 0.0) if va > 0.0 else (min(va + dv, 0.0) if va < 0.0 else dv))
        sd = self.p.noise.imu_speed_sd + self.p.noise.imu_speed_sd_per_s * (t1 - ta)
        return 0.5 * (v[0] + v[1]) * (t1 - t0), sd * (t1 - t0)

    def _wheel_slip(self, t: float) -> bool:
        """Whether the wheels slip at ``t`` (:mod:`.wheel_slip`). When a slip begins the
        estimate has ridden the false odometry for up to the test's window: the gate uses
        the next fixes untested, as after a dead wheel, so they pull it back."""
        if self.slip is None:
            return False
        was = self.slip.since is not None
        slipping = self.slip.update(t)
        if slipping and not was:
            self.gate.unsettle(keep_burst_before=self._trusted_until(self._slip_onset(), "slip"))
        self.leveller.ignore_wheel = slipping
        self.events.extend(self.slip.pop_events())
        return slipping

    def faults(self) -> List[str]:
        """The faults the smoother sees in its inputs now (for /diagnostics), empty when none."""
        out = []
        if self.slip is not None and self.slip.since is not None:
            out.append(f"wheels slip (since {self.slip.since:.1f} s): {self.slip.reason}; odometry ignored")
        if self.dead_wheel.since is not None:
            out.append(f"wheel speed reads 0 while the vehicle moves (since {self.dead_wheel.since:.1f} s): "
                       "odometry ignored")
        return out

    def pop_gps_decisions(self):
        """Every GPS decision since the last call: (fix time, used, reason, d2), see
        :meth:`GpsGate.pop_decisions`."""
        return self.gate.pop_decisions()

    def pop_events(self) -> List[str]:
        ev, self.events = self.events, []
        return ev

    def _pose(self, k: int, values: gtsam.Values) -> Optional[gtsam.Pose2]:
        """Current estimate of keyframe ``k``: from this update's new values or the solution."""
        if values.exists(X(k)):
            return values.atPose2(X(k))
        return self.result.atPose2(X(k)) if self.result.exists(X(k)) else None

    def _add_gps(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        """Decide the pending fixes whose look-ahead group is in (see :mod:`.gps_gate`) and
        add the accepted ones as factors on the keyframe of their measurement time."""
        if not self.p.use_gps:  # the first fix still places the start (see _initialize)
            self.gps_pending.clear()
            return
        g = self.p.gps_gate
        newest_fix = self.gps_pending[-1][0] if self.gps_pending else -math.inf
        keep = []
        innovations: Dict[int, Optional[Tuple[np.ndarray, np.ndarray, gtsam.Pose2, np.ndarray]]] = {}
        newest: Dict[str, Optional[np.ndarray]] = {}  # the newest keyframe's antenna covariance, once

        def innovation(i: int):
            """(innovation, motion-corrected fix, keyframe pose, drift) of pending fix i, None before its keyframe."""
            if i not in innovations:
                t, z = self.gps_pending[i][0], self.gps_pending[i][1]
                k = int(round(t / self.dt))
                pose = self._pose(k, values) if self.oldest_k <= k <= self.k else None
                if pose is None:
                    innovations[i] = None
                else:
                    # Move the fix to the keyframe's time along the current motion (|dt| <= half a period).
                    zc = z - self.latest_speed * (t - self._t(k)) * np.array([math.cos(pose.theta()),
                                                                               math.sin(pose.theta())])
                    drift = self._vector(G(k), values)
                    innovations[i] = (zc - drift - factors.gps_antenna(pose, self.lever), zc, pose, drift)
            return innovations[i]

        for i, (t, z, ve, vn, status) in enumerate(self.gps_pending):
            k = int(round(t / self.dt))
            if k > self.k:
                keep.append(self.gps_pending[i])  # its keyframe does not exist yet
                continue
            if k < self.oldest_k:
                self.gate.skip(TOO_OLD, t)
                continue
            # Wait for the group: a later fix beyond it, or group_wait of silence after it. Not
            # without odometry: the fixes are then all there is, and waiting leaves the newest
            # keyframes to a guess (the group test uses the fixes already in).
            blind = self.no_odometry_t >= self._t(self.k) - g.group
            if (g.group > 0.0 and not blind and newest_fix < t + g.group - 1e-9
                    and self.latest_t < t + g.group + g.group_wait and self._lookahead_worth(t, ve, vn, values, newest)):
                keep.append(self.gps_pending[i])
                continue
            inn = innovation(i)
            if inn is None:
                self.gate.skip(TOO_OLD, t)
                continue
            nu, zc, pose, _ = inn
            R = np.diag([ve, vn])
            group = []
            if g.group > 0.0:
                for j in range(i + 1, len(self.gps_pending)):
                    tj = self.gps_pending[j][0]
                    if tj > t + g.group + 1e-9:
                        break
                    other = innovation(j)
                    if other is not None:
                        group.append((other[0], np.diag(self.gps_pending[j][2:4])))
            antenna = zc - nu  # estimated antenna plus drift
            step = None
            if self.prev_fix is not None and self.prev_fix[0] < t:
                t_p, z_p, k_p, R_p = self.prev_fix
                pose_p = self._pose(k_p, values) if k_p >= self.oldest_k else None
                if pose_p is not None:
                    # Both ends from this solution: a correction of the estimate between the
                    # two decisions is not a step of the fixes (it was: after a freeze of the
                    # odometry the estimate's own recovery opened a "burst" that locked out an
                    # RTK receiver's fixes).
                    a_p = self._vector(G(k_p), values) + factors.gps_antenna(pose_p, self.lever)
                    n = (t - t_p) / self.dt
                    dist = abs(self.latest_speed) * (t - t_p)
                    Q = np.eye(2) * (n * self.p.noise.odometry_xy ** 2 + (self.p.noise.odometry_xy_per_m * dist) ** 2)
                    if t_p <= self.no_odometry_t:
                        # without odometry over the step the estimate's motion is the motion
                        # model's: good to its speed error over one fix period, no better; or
                        # the IMU's speed since the wheel's fault began, good to its own
                        # (blind_speed_sd over a 2.4 s dead wheel let a 3.2 m burst pass for
                        # the estimate's error after 3 s: in it went, and the estimate 3.5 m off)
                        sd = g.blind_speed_sd
                        a = self.imu_anchor
                        if a is not None and self.slip is not None and t - a[0] <= self.slip.p.imu_horizon:
                            sd = min(sd, self.p.noise.imu_speed_sd + self.p.noise.imu_speed_sd_per_s * (t - a[0]))
                        Q = Q + np.eye(2) * (sd * (t - t_p)) ** 2
                    step = ((zc - z_p) - (antenna - a_p), R_p, R, Q)
            self.prev_fix = (t, zc, k, R)
            behind = []
            for t_b, z_b, k_b, R_b in self.decided:
                pose_b = self._pose(k_b, values) if t - g.group - 1e-9 <= t_b and k_b >= self.oldest_k else None
                if pose_b is not None:
                    behind.append((z_b - self._vector(G(k_b), values) - factors.gps_antenna(pose_b, self.lever), R_b))
            self.decided.append((t, zc, k, R))
            bursts, yielded = self.gate.bursts, self.gate.yielded
            verdict = self.gate.decide(t, nu, self._antenna_cov(pose), R, group, step, behind)
            if self.gate.bursts > bursts:
                self.events.append(f"GPS fix at {t:.2f} s jumped {float(np.hypot(*step[0])):.2f} m against the "
                                   "estimated motion: a suspected multipath burst, its fixes rejected until they "
                                   "jump back")
            if self.gate.yielded > yielded:
                self.events.append(f"GPS fixes accepted again at {t:.2f} s after {self.p.gps_gate.yield_after:g} s "
                                   "of rejections (the estimate was lost, not misled)")
            if verdict.use:
                noise = gtsam.noiseModel.Robust.Create(
                    gtsam.noiseModel.mEstimator.Huber.Create(self.p.noise.gps_huber),
                    gtsam.noiseModel.Diagonal.Sigmas(np.sqrt([ve, vn])))
                graph.add(factors.gps_factor(noise, X(k), G(k), zc, self.lever))
                self.counters.gps_used += 1
        self.gps_pending = keep

    def _lookahead_worth(self, t: float, ve: float, vn: float, values: gtsam.Values, newest: Dict) -> bool:
        """GpsGate.lookahead_worth for this fix, with the group's size from the recent fix
        rate; ``newest`` keeps the newest keyframe's antenna covariance for the update's
        other fixes."""
        if "P" not in newest:
            pose = self._pose(self.k, values)
            newest["P"] = None if pose is None else self._antenna_cov(pose)
        if newest["P"] is None:
            return False
        n = 1 + sum(1 for d in self.decided if d[0] > t - self.p.gps_gate.group - 1e-9)
        return self.gate.lookahead_worth(newest["P"], np.diag([ve, vn]), n)

    def _antenna_cov(self, pose: gtsam.Pose2) -> np.ndarray:
        """Covariance of the estimated antenna position plus drift, map axes: the newest
        keyframe's pose marginal (the fixes decided lie within a second or two of it) mapped
        through the lever arm, plus the drift's stationary variance (conservative: the two
        are estimated together and partly cancel)."""
        c, s = math.cos(pose.theta()), math.sin(pose.theta())
        R = np.array([[c, -s], [s, c]])
        J = np.hstack([R, (R @ np.array([-self.lever[1], self.lever[0]]))[:, None]])  # d antenna / d xi (body)
        return J @ self.cov @ J.T + np.eye(2) * self.p.noise.gps_drift ** 2

    def _add_mags(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, now: float) -> None:
        """One factor per ``1 / mag_rate`` s slot: the mean of its readings, on the keyframe
        nearest the slot's centre. A magnetometer's error is mostly model error (tilt,
        the vehicle's currents, soft iron not quite linear) that stays put for seconds: 20
        independent factors a second would claim a precision the readings do not have,
        and that false precision, once marginalised, drags the weakly observable
        heading/hard-iron pair along with every small inconsistency.

        A slot is closed when it is complete: a reading stamped after its end has arrived
        (readings arrive in order) and so has the wheel speed up to its end (the rest
        test), or ``max_wait`` has passed since its end. Closing it one keyframe after its
        end, as this did, assumed the magnetometer is never later than 50 ms: at 150 ms
        (a driver's buffering, or a node waiting for a core at factor 4) the late readings
        of each slot made a second factor of their own, the slot's model error counted
        twice, and the figure eight's heading error went from 0.20 to 0.95 deg RMS
        (offline, 2 seeds). A reading of a slot already closed is dropped and counted."""
        if not self.p.use_mag:
            self.mags.clear()
            return
        period = 1.0 / self.p.mag_rate
        while self.mags:
            j = int(math.floor(self.mags[0][0] / period + 0.5))
            if j <= self.mag_closed:
                self.mags.popleft()
                self.counters.mag_late += 1
                continue
            end = (j + 0.5) * period
            waited = now - end >= self.p.max_wait
            states_in = not self.p.use_odometry or (self.states and self.states.last_t >= end)
            if end > self._t(self.k) or not (waited or (self.mag_newest_t >= end and states_in)):
                break
            ms = []
            while self.mags and int(math.floor(self.mags[0][0] / period + 0.5)) == j:
                ms.append(self.mags.popleft()[1:])
            self.mag_closed = j
            k = int(round(j * period / self.dt))
            if k < self.oldest_k:
                continue
            mk = M(self._c(k))  # the calibration state keyframe k uses
            if not (values.exists(mk) or self.result.exists(mk)):
                continue
            if self._at_rest((j - 0.5) * period, end):
                # Standing still, the magnetometer sees the same field with the same error:
                # one factor per stop, not one per slot (the rest would be false information).
                if self.mag_at_rest:
                    self.counters.mag_skipped_at_rest += 1
                    continue
                self.mag_at_rest = True
            else:
                self.mag_at_rest = False
            graph.add(factors.mag_factor(self._mag_noise(len(ms)), X(k), mk, np.mean(ms, axis=0), self.h_en))
            self.counters.mag_used += 1

    def _at_rest(self, t0: float, t1: float) -> bool:
        """Whether the wheel speed stayed below ``REST_SPEED`` over ``[t0, t1]`` (false without odometry)."""
        if not self.p.use_odometry or not self.states or self.states.last_t < t1:
            return False
        inside = [abs(v) for v, _ in self.states.between(t0 - 0.1, t1)]
        return bool(inside) and max(inside) < self.REST_SPEED

    def _mag_noise(self, n_readings: int):
        n = self.p.noise
        sigma = math.sqrt(n.mag ** 2 + n.mag_white ** 2 / max(1, n_readings))
        return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(n.mag_huber),
                                              gtsam.noiseModel.Isotropic.Sigma(2, sigma))

    def _trim(self, now: float) -> None:
        """Forget sensor data older than the window."""
        horizon = now - self.p.lag - 1.0
        self.states.trim(horizon)
        self.gyro.trim(horizon)
        while self.mags and self.mags[0][0] < horizon:
            self.mags.popleft()
        self.gps_pending = [g for g in self.gps_pending if g[0] >= horizon]

    # ---------------------------------------------------------------- output
    def _estimate(self) -> Optional[Estimate]:
        if self.k is None or not self.result.exists(X(self.k)):
            return None
        pose = self.result.atPose2(X(self.k))
        ck = self._c(self.k)
        kin, mag = self.result.atVector(K(ck)), self.result.atVector(M(ck))
        bias = float(self.result.atVector(B(ck))[0])
        # GTSAM's Pose2 covariance is in the body-frame tangent space: rotate to map axes.
        c, s = math.cos(pose.theta()), math.sin(pose.theta())
        Rb = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        cov = Rb @ self.cov @ Rb.T
        calib = dict(zip(CALIBRATION_NAMES, [float(kin[0]), float(kin[1]), float(kin[2]), bias] +
                         [float(m) for m in mag]))
        return Estimate(self._t(self.k), pose.x(), pose.y(), pose.theta(), self.z or 0.0, self.leveller.roll,
                        self.leveller.pitch, cov,
                        self.latest_speed, self.latest_rate, calib)

    def calibration_sigma(self) -> Dict[str, float]:
        """Standard deviations of the calibration (marginal covariances: call at a low rate)."""
        if self.smoother is None:
            return {}
        try:
            c = self._c(self.k)
            ck = np.sqrt(np.diag(self.smoother.marginalCovariance(K(c))))
            cm = np.sqrt(np.diag(self.smoother.marginalCovariance(M(c))))
            cb = math.sqrt(self.smoother.marginalCovariance(B(c))[0, 0])
        except RuntimeError:
            return {}
        return dict(zip(CALIBRATION_NAMES, [float(ck[0]), float(ck[1]), float(ck[2]), cb] + [float(v) for v in cm]))

