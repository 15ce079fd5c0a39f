"""The predictor's core in Python: the smoother's estimate carried forward with the
bicycle model over the wheel speed and handlebar readings.

A line-for-line port of ``include/quadrivio_localization/predictor.h`` (the roscpp
predictor's core) and of its node's rules for when not to predict (``~max_age``,
``~max_dead_reckoning`` after ``~estimate_age_floor``, an estimate from the future), for
the one-process closed loop (:mod:`quadrivio.closed_loop`), which has no roscpp.
``test/test_predictor_port.py`` checks it against the C++ core on random cases.

    x' = k_v v cos(theta),  y' = k_v v sin(theta),  theta' = k_v v tan(delta) / L,
    delta = clamp(k_d * ratio * (h + h_0), +-max_delta)

Between readings the previous reading is held; past the newest one it is extrapolated.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import List, Optional, Tuple

from quadrivio_config import param


@dataclass(frozen=True)
class PredictorParams:
    """The predictor node's parameters (``config/predictor.yaml``) that decide what it publishes."""
    rate: float = param(50.0, lo=0.1, hi=1000.0, unit="Hz", doc="rate of localization/predicted")
    horizon: float = param(0.0, lo=0.0, hi=2.0, unit="s", doc="predict this far beyond now")
    max_age: float = param(1.0, lo=1e-3, hi=60.0, unit="s", doc="no prediction from an older estimate")
    max_dead_reckoning: float = param(0.5, lo=1e-3, hi=100.0, unit="m",
                                      doc="no prediction past this distance driven on odometry alone...")
    estimate_age_floor: float = param(0.15, lo=0.0, hi=60.0, unit="s", doc="...from an estimate older than this")
    max_future: float = param(0.5, lo=0.0, hi=60.0, unit="s", doc="an estimate further ahead of the clock is refused")


class Predictor:
    KEEP = 10.0  # [s] of readings kept

    def __init__(self, wheelbase: float, ratio: float, max_delta: float) -> None:
        self.L, self.ratio, self.max_delta = wheelbase, ratio, max_delta
        self.speed_scale, self.handlebar_offset, self.steering_gain = 1.0, 0.0, 1.0
        self.readings: List[Tuple[float, float, float]] = []  # (t, speed, handlebar), in time order
        self._times: List[float] = []  # their times (bisect)
        self.est = (0.0, 0.0, 0.0)
        self.est_t = 0.0
        self.has_estimate = False

    def set_calibration(self, speed_scale: float, handlebar_offset: float, steering_gain: float) -> bool:
        if not all(map(math.isfinite, (speed_scale, handlebar_offset, steering_gain))):
            return False
        self.speed_scale, self.handlebar_offset, self.steering_gain = speed_scale, handlebar_offset, steering_gain
        return True

    def set_estimate(self, t: float, x: float, y: float, theta: float) -> bool:
        if not all(map(math.isfinite, (x, y, theta))):
            return False
        self.est_t, self.est, self.has_estimate = t, (x, y, theta), True
        return True

    def add_reading(self, t: float, speed: float, handlebar: float) -> bool:
        if not all(map(math.isfinite, (t, speed, handlebar))):
            return False
        if self.readings and t < self.readings[-1][0]:
            return False
        self.readings.append((t, speed, handlebar))
        self._times.append(t)
        # the C++ core drops readings older than KEEP one by one; dropped here in batches (the
        # predictions are the same: a prediction starts at the reading in force at the estimate)
        if len(self._times) > 64 and self._times[32] < t - self.KEEP:
            k = bisect.bisect_left(self._times, t - self.KEEP, 1, len(self._times) - 2) - 1
            if k > 0:
                del self.readings[:k]
                del self._times[:k]
        return True

    def _delta(self, handlebar: float) -> float:
        d = self.steering_gain * self.ratio * (handlebar + self.handlebar_offset)
        return max(-self.max_delta, min(self.max_delta, d))

    def step(self, p, speed: float, handlebar: float, dt: float):
        """One exact arc for constant speed and handlebar over ``dt``."""
        x, y, th = p
        v = self.speed_scale * speed
        w = v * math.tan(self._delta(handlebar)) / self.L
        dth = w * dt
        if abs(dth) < 1e-9:
            return (x + v * dt * math.cos(th + 0.5 * dth), y + v * dt * math.sin(th + 0.5 * dth), th + dth)
        r = v / w
        return (x + r * (math.sin(th + dth) - math.sin(th)), y - r * (math.cos(th + dth) - math.cos(th)), th + dth)

    def predict(self, target: float) -> Tuple[Tuple[float, float, float], float]:
        """(the estimate carried to ``target``, the distance driven on odometry to get there [m])."""
        p, t, travelled = self.est, self.est_t, 0.0
        rd = self.readings
        if target <= t or not rd:
            return p, travelled
        # the reading in force at t: the newest one not after t (or the first one)
        i = max(0, bisect.bisect_right(self._times, t) - 1)
        while t < target:
            nxt = max(t, min(target, rd[i + 1][0])) if i + 1 < len(rd) else target
            p = self.step(p, rd[i][1], rd[i][2], nxt - t)
            travelled += abs(self.speed_scale * rd[i][1]) * (nxt - t)
            t = nxt
            if i + 1 < len(rd) and t >= rd[i + 1][0]:
                i += 1
        return p, travelled

    def latest(self) -> Optional[Tuple[float, float]]:
        """(speed, yaw rate) of the newest reading, calibrated; None without one."""
        if not self.readings:
            return None
        _, s, h = self.readings[-1]
        v = self.speed_scale * s
        return v, v * math.tan(self._delta(h)) / self.L


def predicted(core: Predictor, p: PredictorParams, now: float):
    """What the node publishes at ``now``: ``(stamp, (x, y, theta), (speed, yaw rate), "")``,
    or ``(None, None, None, why)`` when it publishes nothing (no estimate, one too old or
    from the future, too far driven on odometry since it)."""
    if not core.has_estimate:
        return None, None, None, "no estimate"
    age = now - core.est_t
    if age < -p.max_future:
        return None, None, None, f"the estimate is {-age:.2f} s ahead of the clock"
    if age > p.max_age:
        return None, None, None, f"the estimate is {age:.2f} s old"
    target = now + p.horizon
    pose, travelled = core.predict(target)
    if age > p.estimate_age_floor and travelled > p.max_dead_reckoning:
        return None, None, None, f"the estimate is {age:.2f} s old and {travelled:.2f} m were driven on odometry since"
    return target, pose, core.latest() or (0.0, 0.0), ""
