"""Dead reckoning on the calibrated kinematic model: the continuous odom -> base_link."""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Deque, Optional, Tuple

from quadrivio_description.kinematics import arc, compose


class DeadReckoning:
    """Integrates wheel speed and handlebar samples with calibration ``(k_v, h_0, k_d)``.

    Between samples the model holds the previous sample's values (the PLC reports at
    50 Hz). :meth:`pose_at` interpolates the history for the map -> odom correction.
    """

    def __init__(self, wheelbase: float, ratio: float, limit: float, history: int = 2000) -> None:
        """``limit``: the virtual wheel angle limit [rad] (kinematics.max_delta of the vehicle)."""
        self.L, self.ratio, self.limit = wheelbase, ratio, limit
        self.calib = (1.0, 0.0, 1.0)
        self.t: Optional[float] = None
        self.v = self.h = 0.0
        self.pose = (0.0, 0.0, 0.0)
        self.history: Deque[Tuple[float, float, float, float]] = deque(maxlen=history)
        self.rejected = 0

    def add(self, t: float, speed: float, handlebar: float) -> Tuple[float, float, float]:
        """Integrate up to ``t`` and hold the new sample; a non-finite one is ignored
        (counted in ``rejected``): one NaN must not poison the pose for good."""
        if not all(math.isfinite(x) for x in (t, speed, handlebar)):
            self.rejected += 1
            return self.pose
        if self.t is not None and t > self.t:
            d, _ = arc(t - self.t, self.v, self.h, self.calib, self.L, self.ratio, self.limit)
            self.pose = compose(self.pose, d)
        if self.t is None or t >= self.t:
            self.t, self.v, self.h = t, speed, handlebar
            self.history.append((t, *self.pose))
        return self.pose

    def pose_at(self, t: float) -> Optional[Tuple[float, float, float]]:
        """Odom pose at ``t`` (linear interpolation; None outside the history)."""
        if not self.history or t < self.history[0][0] or t > self.history[-1][0]:
            return None
        times = [h[0] for h in self.history]
        i = bisect.bisect_left(times, t)
        if times[i] == t or i == 0:
            return self.history[i][1:]
        (t0, *a), (t1, *b) = self.history[i - 1], self.history[i]
        w = (t - t0) / (t1 - t0)
        dth = math.remainder(b[2] - a[2], 2 * math.pi)
        return (a[0] + w * (b[0] - a[0]), a[1] + w * (b[1] - a[1]), a[2] + w * dth)
