"""Input guards for nodes: finite values and plausible stamps, every reject counted.

One bad message must never break a node: a NaN wheel speed that poisons dead reckoning,
an IMU sample stamped 1000 s ahead that makes every later sample look out of order, an
inf that latches a filter. :class:`InputGuard` checks a message's values and stamp
before the node's core sees it and counts what it rejects by input and reason (for
``/diagnostics``); the node drops the message and goes on.

A stamp is implausible when it is more than ``max_future`` ahead of the node's clock (no
measurement comes from the future; sim time is shared by every node, so the tolerance
only covers transport) or more than ``max_age`` behind it. A clock that is not running
yet (``now <= 0``) checks nothing.
"""

from __future__ import annotations

import math
from collections import Counter
from typing import Callable, Dict, Optional, Tuple


def finite(*values: float) -> bool:
    try:
        return all(math.isfinite(v) for v in values)
    except TypeError:
        return False


class InputGuard:
    """Counts of rejected inputs by ``(input, reason)``; ``log(text)`` hears each reject."""

    def __init__(self, max_future: float = 0.5, max_age: float = math.inf,
                 log: Optional[Callable[[str], None]] = None) -> None:
        if not (max_future >= 0.0 and max_age > 0.0):
            raise ValueError(f"max_future {max_future} must be >= 0 and max_age {max_age} > 0")
        self.max_future, self.max_age = max_future, max_age
        self.log = log
        self.counts: Counter = Counter()
        self.last = ""

    def reject(self, what: str, reason: str, detail: str = "") -> bool:
        """Count one rejected input; always False (so ``return guard.reject(...)`` reads well)."""
        self.counts[(what, reason)] += 1
        self.last = f"{what}: {reason}{' (' + detail + ')' if detail else ''}; dropped"
        if self.log is not None:
            self.log(self.last)
        return False

    def values(self, what: str, *values: float) -> bool:
        """True when every value is a finite number."""
        if finite(*values):
            return True
        return self.reject(what, "value not finite", ", ".join(repr(v) for v in values if not finite(v)))

    def stamp(self, what: str, stamp: float, now: float) -> bool:
        """True when ``stamp`` is finite and within ``[now - max_age, now + max_future]``."""
        if not finite(stamp) or stamp < 0.0:
            return self.reject(what, "bad stamp", repr(stamp))
        if now <= 0.0:
            return True
        if stamp > now + self.max_future:
            return self.reject(what, "stamp from the future", f"{stamp - now:.3f} s ahead of now {now:.3f} s")
        if stamp < now - self.max_age:
            return self.reject(what, "stamp too old", f"{now - stamp:.3f} s behind now {now:.3f} s")
        return True

    def check(self, what: str, stamp: float, now: float, *values: float) -> bool:
        return self.stamp(what, stamp, now) and self.values(what, *values)

    @property
    def total(self) -> int:
        return sum(self.counts.values())

    def by_input(self) -> Dict[str, int]:
        out: Dict[str, int] = {}
        for (what, _), n in self.counts.items():
            out[what] = out.get(what, 0) + n
        return out

    def table(self) -> Dict[Tuple[str, str], int]:
        return dict(self.counts)

    def summary(self) -> str:
        """``"imu: 3 x stamp from the future; gps: 1 x value not finite"`` (or ``"none"``)."""
        if not self.counts:
            return "none"
        return "; ".join(f"{what}: {n} x {reason}" for (what, reason), n in sorted(self.counts.items()))
