"""Time-ordered sensor samples held as a step function: each sample's value stands from
its stamp until the next sample's (the last one until whenever it is asked about).

The smoother keeps its wheel-speed/handlebar and gyro samples here and asks, per
keyframe interval, for the pieces of the step function inside it (odometry), its
integral (the gyro's heading change) or the values inside it (standstill). Lookups are
binary searches on the stamps; nothing is rebuilt per query.
"""

from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Deque, Generic, List, Optional, Tuple, TypeVar

V = TypeVar("V")


class SampleBuffer(Generic[V]):
    """Samples ``(t, value)`` appended in time order, at most ``maxlen`` kept."""

    def __init__(self, maxlen: int = 20000) -> None:
        self.t: Deque[float] = deque(maxlen=maxlen)
        self.v: Deque[V] = deque(maxlen=maxlen)

    def __len__(self) -> int:
        return len(self.t)

    def __bool__(self) -> bool:
        return bool(self.t)

    @property
    def last_t(self) -> Optional[float]:
        return self.t[-1] if self.t else None

    @property
    def last(self) -> Optional[V]:
        return self.v[-1] if self.v else None

    def append(self, t: float, value: V) -> bool:
        """Add a sample; refused (False) when older than the newest one."""
        if self.t and t < self.t[-1]:
            return False
        self.t.append(t)
        self.v.append(value)
        return True

    def trim(self, horizon: float) -> None:
        """Forget samples no longer needed for times from ``horizon`` on (the one in force
        at ``horizon`` is kept, and always the last two)."""
        while len(self.t) > 2 and self.t[1] < horizon:
            self.t.popleft()
            self.v.popleft()

    def _at(self, t: float) -> int:
        """Index of the sample in force at ``t`` (-1 before the first)."""
        return bisect.bisect_right(self.t, t) - 1

    def pieces(self, t0: float, t1: float, max_hold: float = math.inf) -> List[Tuple[float, V]]:
        """``(duration, value)`` of the step function over ``[t0, t1]``; empty when no
        sample is in force at ``t0``, or when a sample would have to stand for more than
        ``max_hold`` s past its stamp somewhere in the interval (a gap in the data: the
        value before it says nothing of the time inside it)."""
        i = self._at(t0)
        if i < 0:
            return []
        out: List[Tuple[float, V]] = []
        n, t = len(self.t), t0
        while t < t1 - 1e-12 and i < n:
            end = min(t1, max(self.t[i + 1], t)) if i + 1 < n else t1
            if end > t:
                if end - self.t[i] > max_hold + 1e-9:
                    return []
                out.append((end - t, self.v[i]))
            t = end
            i += 1
        return out

    def integral(self, t0: float, t1: float, max_hold: float = math.inf) -> Optional[float]:
        """Integral of a scalar step function over ``[t0, t1]``; None when :meth:`pieces`
        gives none."""
        pieces = self.pieces(t0, t1, max_hold)
        if not pieces:
            return None
        return sum(dt * float(v) for dt, v in pieces)

    def between(self, t0: float, t1: float) -> List[V]:
        """The values of the samples stamped in ``[t0, t1]``."""
        i0 = bisect.bisect_left(self.t, t0)
        i1 = bisect.bisect_right(self.t, t1)
        return [self.v[i] for i in range(i0, i1)]

    def stamped(self, t0: float, t1: float) -> List[Tuple[float, V]]:
        """``(t, value)`` of the samples stamped in ``[t0, t1]``."""
        i0 = bisect.bisect_left(self.t, t0)
        i1 = bisect.bisect_right(self.t, t1)
        return [(self.t[i], self.v[i]) for i in range(i0, i1)]
