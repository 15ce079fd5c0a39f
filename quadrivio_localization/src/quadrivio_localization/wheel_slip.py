"""Wheels that report motion the IMU and the GPS deny: spinning against an obstacle, on mud,
on a slope the vehicle cannot climb.

Pushing against a wall the driven wheels spin at the speed the PLC asks for while the body
stands; believed, the odometry drove the estimate through the wall at the wheels' speed,
and the GPS gate, judging the fixes by that estimate, rejected every fix as multipath (24 m
off in the orchard, the fixes all at the truth). Two tests, either of which starts a slip:

* **IMU**: over the last ``window`` s the wheel speed changed by ``dv_w`` while the body's
  forward acceleration, from the accelerometer with gravity taken out
  (``dv/dt = f_x + g sin(pitch)``, REP-103 pitch positive nose down), integrates to
  ``dv_i``: a slip when the wheel gained more than the body in the direction of motion,
  ``sgn(v) (dv_w - dv_i) > max(threshold, fraction |dv_w|, sigmas rms)``, ``rms`` the
  discrepancy's own root mean square over the last ``noise_tau`` s without a slip: on flat
  ground about 0.1 m/s, on 8 cm bumps at 3 m/s 0.15-0.3 m/s (the wheel climbs each bump
  face and spins up as a bump unloads it), where a fixed threshold of 0.8 m/s is 3 of them
  and fired on bumps (20 false slips in 20 rough-terrain runs). A wheel that spins up while
  the body does not accelerate, or a body that stops dead (an impact) while the wheel
  turns on, both show within ``window`` (a wheel that loses speed the body keeps is a
  locked one: :mod:`.wheel_lock`). The pitch is the guard's complementary filter
  (:class:`quadrivio_description.attitude.Attitude`: the gyro's exact Euler rates, the
  IMU's lever arm and the gyro's bias taken out, pulled toward the accelerometer's tilt
  with the wheel's acceleration taken out), fed no wheel speed in a slip (then the gyro
  alone carries it). Over the window the pitch at its start is carried on by the gyro's
  pitch rate alone, since the filter's pull uses the wheel under test. On rough ground the
  pitch swings by degrees within a second, and a pitch 3 deg off is 0.5 m/s^2: a filter of
  its own (the gyro's pitch axis alone, no lever arm, no bias) put the IMU's speed change
  over 0.5 s 0.19 m/s RMS off the truth on 8 cm bumps at 3 m/s.
* **GPS**: the fixes of the last ``gps_window`` s, when they are mutually consistent (a
  straight-line fit of east and north over time leaves residuals within their reported
  noise: no jump, no burst inside), move at ``v_g``; a slip when the wheel's mean speed
  over the same time exceeds it by more than ``max(threshold, gps_sigmas sigma_v)``, with
  ``sigma_v`` the fitted speed's standard deviation.

A slip holds until the wheel reads rest, or the body's speed integrated from the IMU since
the slip began meets the wheel's again for ``recover_time`` within ``imu_horizon`` of its
start (the tyres found grip; later the integration has drifted too far to tell), or the
fixes move as fast as the wheel says. Meanwhile the smoother takes no odometry (for
``imu_horizon`` s from the fault's onset the IMU's speed, :meth:`WheelSlip.body_change`,
then the vehicle keeps its motion, give or take ``no_odometry_accel``) and uses the fixes
untested.

Pure and ROS-free; the smoother feeds it its wheel speeds, IMU samples and fixes in time order.
"""

from __future__ import annotations

import math
import bisect
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from quadrivio_description.attitude import Attitude

G = 9.80665  # [m/s^2]


@dataclass(frozen=True)
class SlipParams:
    window: float = 0.5  # [s] the IMU test's window
    threshold: float = 0.7  # [m/s] smallest speed discrepancy called a slip
    fraction: float = 0.5  # [1] ... and at least this fraction of the wheel's change
    sigmas: float = 4.0  # [1] ... and at least this many of the discrepancy's recent RMS
    noise_tau: float = 10.0  # [s] the time constant of that RMS
    gps_window: float = 3.0  # [s] the GPS test's window
    gps_sigmas: float = 4.0  # [1]
    gps_min_fixes: int = 6
    consistency: float = 4.0  # [1] mean squared normalised residual of the fixes' line fit
    recover_time: float = 1.0  # [s]
    attitude_tau: float = 4.0  # [s] the attitude filter's time constant
    imu_horizon: float = 3.0  # [s] the IMU's integrated speed is believed this long into a slip (then it
    #                           drifts: a pitch 1 deg off is 0.17 m/s^2, and a pushing vehicle squats)
    rest_speed: float = 0.05  # [m/s]


class _Stream:
    """Time-ordered samples in parallel lists, trimmed in halves (bisect, no deque scans)."""

    def __init__(self) -> None:
        self.t: List[float] = []
        self.rows: List[tuple] = []

    def append(self, t: float, row: tuple) -> bool:
        if self.t and t <= self.t[-1]:
            return False
        self.t.append(t)
        self.rows.append(row)
        return True

    def trim(self, before: float) -> None:
        if len(self.t) > 64 and self.t[len(self.t) // 2] < before:
            del self.t[:len(self.t) // 2], self.rows[:len(self.rows) // 2]

    def at(self, t: float) -> Optional[tuple]:
        """The newest row at or before ``t``."""
        i = bisect.bisect_right(self.t, t + 1e-9) - 1
        return self.rows[i] if i >= 0 else None

    def between(self, t0: float, t1: float) -> List[tuple]:
        i, j = bisect.bisect_left(self.t, t0), bisect.bisect_right(self.t, t1 + 1e-9)
        return self.rows[i:j]


class WheelSlip:
    def __init__(self, p: SlipParams = SlipParams(), lever: Sequence[float] = (0.0, 0.0, 0.0)) -> None:
        """``lever``: the IMU's position in base_link [m]."""
        self.p = p
        self.attitude = Attitude(p.attitude_tau, lever=lever, start_band=0.1)
        self.speeds = _Stream()  # (v,)
        # (f_x, pitch rate, filtered pitch, integral of f_x, integral of the pitch rate (pitch change), integral
        # of that, the x of w x lever: the IMU's speed over base_link's)
        self.imu = _Stream()
        self.fixes = _Stream()  # (e, n, variance)
        self.since: Optional[float] = None  # the slip's start, None without one
        self.body_speed = 0.0  # [m/s] integrated from the IMU since the slip began
        self.body_t: Optional[float] = None
        self.pitch0 = 0.0
        self.u0 = 0.0  # w x lever's x at the slip's start
        self.matched_since: Optional[float] = None
        self.ended = -math.inf  # when the last slip ended (the GPS test looks at later fixes only)
        self.reason = ""
        self.noise_ms = 0.0  # [m^2/s^2] the IMU test's discrepancy's mean square without a slip
        self.noise_t: Optional[float] = None
        self.events: List[str] = []
        self.slips = 0
        self._gps_cache: Tuple[Optional[float], Optional[float], object] = (None, None, None)

    # ------------------------------------------------------------------ input
    def add_speed(self, t: float, v: float) -> None:
        if self.speeds.append(t, (v,)) and self.since is None:
            self.attitude.add_speed(t, v)  # in a slip the wheel's acceleration is not the body's
        self.speeds.trim(t - self._keep())

    def _keep(self) -> float:
        return max(self.p.window, self.p.gps_window) + 1.0

    def add_imu(self, t: float, f: Sequence[float], w: Sequence[float]) -> None:
        """Specific force [m/s^2] and angular rate [rad/s] in base_link (REP-103)."""
        if self.imu.t and t <= self.imu.t[-1]:
            return
        att = self.attitude
        if not att.started and len(self.speeds.t) < 2:
            return  # the filter starts on the accelerometer's tilt: with the wheel's acceleration out of it
        att.add_imu(t, f, w)
        fx = att.f_origin[0]
        rate = w[1] * math.cos(att.roll) - w[2] * math.sin(att.roll) - att.bias_pitch  # the pitch's rate
        u = w[1] * att.lever[2] - w[2] * att.lever[1]
        cf = th = cth = 0.0
        if self.imu.t:
            prev_t, (_, _, _, cf, th, cth, _) = self.imu.t[-1], self.imu.rows[-1]
            dt = t - prev_t
            cf += fx * dt
            th += rate * dt
            cth += th * dt
        self.imu.append(t, (fx, rate, att.pitch, cf, th, cth, u))
        self.imu.trim(t - self._keep())
        if self.since is not None:
            if self.body_t is not None:
                dt = t - self.body_t
                self.pitch0 += rate * dt
                self.body_speed += (fx + G * math.sin(self.pitch0)) * dt
            self.body_t = t

    def imu_speed(self) -> float:
        """In a slip: the body's speed [m/s] from the IMU since its start."""
        return self.body_speed - ((self.imu.rows[-1][6] if self.imu.rows else self.u0) - self.u0)

    def add_fix(self, t: float, e: float, n: float, variance: float) -> None:
        if self.fixes.append(t, (e, n, variance)):
            self.fixes.trim(t - self._keep())

    # ----------------------------------------------------------------- tests
    def speed_at(self, t: float) -> Optional[float]:
        """The newest wheel speed at or before ``t`` [m/s]."""
        row = self.speeds.at(t)
        return row[0] if row is not None else None

    def _imu_test(self, t: float) -> Optional[str]:
        p = self.p
        t0 = t - p.window
        v0, v1 = self.speed_at(t0), self.speed_at(t)
        if v0 is None or v1 is None or not self.imu.t or self.imu.t[0] > t0:
            return None
        dv_i = self.body_change(t0, t)
        if dv_i is None:
            return None
        dv_w = v1 - v0
        sign = 1.0 if v1 + v0 >= 0.0 else -1.0
        d = sign * (dv_w - dv_i)
        rms = math.sqrt(self.noise_ms)
        if d > max(p.threshold, p.fraction * abs(dv_w), p.sigmas * rms):
            return (f"the wheel speed changed by {dv_w:+.2f} m/s in {p.window:g} s, the IMU says the body by "
                    f"{dv_i:+.2f} m/s (recent RMS of the difference {rms:.2f} m/s)")
        # no slip: the discrepancy is the two measurements' noise on this ground
        if self.noise_t is not None and 0.0 < t - self.noise_t < 1.0:  # not across a gap (rest, a slip)
            k = min(1.0, (t - self.noise_t) / p.noise_tau)
            self.noise_ms += k * (d * d - self.noise_ms)
        self.noise_t = t
        return None

    def body_change(self, t0: float, t1: float) -> Optional[float]:
        """The body's speed change over ``(t0, t1]`` from the IMU: the specific force's
        integral plus gravity at the filter's pitch at ``t0`` carried on by the gyro alone
        (``sin(p0 + d) ~ sin(p0) + cos(p0) d``: a window is short), since the filter's pull
        uses the wheel that is under test."""
        a, b = self.imu.at(t0), self.imu.at(t1)
        if a is None or b is None:
            return None
        ta = self.imu.t[bisect.bisect_right(self.imu.t, t0 + 1e-9) - 1]
        tb = self.imu.t[bisect.bisect_right(self.imu.t, t1 + 1e-9) - 1]
        w = tb - ta
        p0 = a[2]
        drift = (b[5] - a[5]) - a[4] * w  # integral of the pitch change since ta
        # the specific force at the IMU also holds the lever's tangential acceleration (alpha x r),
        # whose integral is the change of w x r: exact from two gyro readings (no differencing)
        return (b[3] - a[3]) + G * math.sin(p0) * w + G * math.cos(p0) * drift - (b[6] - a[6])

    def gps_speed(self, t: float) -> Optional[Tuple[float, float, float]]:
        """(speed, its sd, mean wheel speed) over the GPS window, when the fixes there are
        many enough and mutually consistent; else None. Computed once per new fix (the
        window moves with the fixes)."""
        newest = self.fixes.t[-1] if self.fixes.t else None
        if self._gps_cache[0] == newest and self._gps_cache[1] is not None and t - self._gps_cache[1] < 0.3:
            return self._gps_cache[2]
        got = self._gps_fit(t)
        self._gps_cache = (newest, t, got)
        return got

    def _gps_fit(self, t: float) -> Optional[Tuple[float, float, float]]:
        p = self.p
        rows = self.fixes.between(t - p.gps_window, t)
        if len(rows) < p.gps_min_fixes:
            return None
        i = bisect.bisect_left(self.fixes.t, t - p.gps_window)
        ts = np.array(self.fixes.t[i:i + len(rows)])
        a = np.array(rows)
        tt = ts - ts.mean()
        if float(np.ptp(tt)) < 0.5 * p.gps_window:
            return None
        w = 1.0 / a[:, 2]
        A = np.column_stack([np.ones_like(tt), tt])
        AtW = A.T * w
        N = AtW @ A
        try:
            Ninv = np.linalg.inv(N)
        except np.linalg.LinAlgError:
            return None
        chi2, vel = 0.0, []
        for col in (0, 1):
            coef = Ninv @ (AtW @ a[:, col])
            r = a[:, col] - A @ coef
            chi2 += float(np.sum(w * r * r))
            vel.append(coef[1])
        if chi2 / (2 * len(a) - 4) > p.consistency:
            return None  # not one steady stream (a jump, a burst inside)
        sd = math.sqrt(Ninv[1, 1])
        ws = [r[0] for r in self.speeds.between(float(ts[0]), t)]
        if not ws:
            return None
        return math.hypot(*vel), sd, float(np.mean(np.abs(ws)))

    def _gps_test(self, t: float) -> Optional[str]:
        if t - self.p.gps_window < self.ended:
            return None  # the window still holds the last slip's wheel speeds
        got = self.gps_speed(t)
        if got is None:
            return None
        v_g, sd, v_w = got
        if v_w - v_g > max(self.p.threshold, self.p.gps_sigmas * sd):
            return (f"the wheels say {v_w:.2f} m/s, the consistent GPS fixes of the last "
                    f"{self.p.gps_window:g} s say {v_g:.2f} m/s")
        return None

    # ------------------------------------------------------------------ state
    def update(self, t: float) -> bool:
        """Whether the wheels slip at ``t`` (the events to log in :attr:`events`)."""
        p = self.p
        v = self.speed_at(t)
        if self.since is None:
            if v is None or abs(v) < p.rest_speed:
                return False  # a wheel at rest claims no motion (a locked wheel is wheel_lock's)
            why = self._imu_test(t) or self._gps_test(t)
            if why is None:
                return False
            self.since, self.reason = t, why
            self.slips += 1
            before = self.speed_at(t - p.window)
            # the body's speed since the window's start (the slip is seen at its end)
            a0, a1 = self.imu.at(t - p.window), self.imu.at(t)
            dv = self.body_change(t - p.window, t) or 0.0
            # the pitch before the window (the filter was not misled yet), on by the gyro
            self.pitch0 = a0[2] + (a1[4] - a0[4]) if a0 is not None and a1 is not None else 0.0
            self.body_speed = (before if before is not None else 0.0) + dv
            self.u0 = a1[6] if a1 is not None else 0.0
            self.body_t = t
            self.matched_since = None
            self.events.append(f"wheels slip at {t:.2f} s: {why}; odometry ignored while it lasts")
            return True
        # in a slip: does the wheel tell the truth again?
        ended = ""
        if v is not None and abs(v) < p.rest_speed:
            ended = "the wheel reads rest"
        else:
            got = self.gps_speed(t)
            if got is not None and abs(got[2] - got[0]) <= max(p.threshold, p.gps_sigmas * got[1]) and \
                    t - self.since >= p.gps_window:
                ended = f"the fixes move at the wheels' {got[2]:.2f} m/s"
            elif v is not None and t - self.since <= p.imu_horizon and abs(v - self.imu_speed()) < p.threshold:
                if self.matched_since is None:
                    self.matched_since = t
                if t - self.matched_since >= p.recover_time:
                    ended = "the body's speed from the IMU meets the wheel's"
            else:
                self.matched_since = None
        if ended:
            self.events.append(f"wheel slip over at {t:.2f} s after {t - self.since:.1f} s: {ended}")
            self.since, self.ended = None, t
            return False
        return True

    def pop_events(self) -> List[str]:
        ev, self.events = self.events, []
        return ev
