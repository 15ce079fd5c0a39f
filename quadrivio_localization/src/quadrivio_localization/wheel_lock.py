"""The wheel's two lies the smoother checks for: a locked wheel (:class:`WheelLock`) and a
dead wheel-speed channel (:class:`DeadWheel`).

A locked wheel: a wheel speed that drops faster than any vehicle brakes on its tyres.

Under a full brake a wheel can lock: it reads 0 at once while the vehicle slides on.
Believed, that standstill falls short of where the vehicle went (0.3 m on a full brake
from 3 m/s in the simulator), and the GPS gate took the next fix for a multipath burst.

A drop is measured over ``span`` s at least (one sample of an encoder's noise is no
deceleration) and is a lock once the next wheel speed stays down too. The lock holds
while the wheel reads no more than it did after the drop (by ``rest_speed``), for at most
the time the vehicle would take to stop from the speed before the drop at ``stop_accel``:
then the wheel's standstill is the vehicle's. Each wheel speed is judged once, in order.

Pure and ROS-free; the smoother feeds it its buffered wheel speeds.
"""

from __future__ import annotations

import bisect
from typing import List, Optional, Sequence, Tuple


class WheelLock:
    def __init__(self, decel: float, stop_accel: float, rest_speed: float, span: float) -> None:
        self.decel = decel  # [m/s^2] a faster drop is a lock (0: never)
        self.stop_accel = max(stop_accel, 0.1)  # [m/s^2] the vehicle stops at least this fast
        self.rest_speed = rest_speed  # [m/s] the wheel turns again when it reads this much more
        self.span = span  # [s] the shortest interval a drop is measured over
        self.seen = -float("inf")  # the newest wheel speed judged
        self.since: Optional[float] = None  # the drop's time, None without a lock
        self.until = 0.0  # the lock ends here at the latest
        self.floor = 0.0  # the lowest wheel speed read since the drop
        self.confirmed = False  # the wheel speed after the drop stayed down
        self.drop: Tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # (ta, va, tb, vb) of the drop

    def update(self, speeds: Sequence[Tuple[float, float]], t0: float) -> Tuple[bool, List[str]]:
        """Judge the wheel speeds ``(t, v)`` not judged yet (``speeds`` in time order, reaching
        ``span`` s before the first new one); whether the wheel is locked for the interval
        starting at ``t0``, and the events to log (a lock, once confirmed)."""
        events: List[str] = []
        if self.decel <= 0.0:
            return False, events
        ts = [t for t, _ in speeds]
        for tb, vb in speeds:
            if tb <= self.seen:
                continue
            self.seen = tb
            vb = abs(vb)
            if self.since is not None and tb > self.since:
                if vb > self.floor + self.rest_speed:
                    self.since = None  # it turns again
                else:
                    self.floor = min(self.floor, vb)
                    if not self.confirmed:  # it stayed down: a lock
                        self.confirmed = True
                        ta, va, tdrop, vdrop = self.drop
                        events.append(f"wheel speed dropped from {va:.2f} to {vdrop:.2f} m/s in {tdrop - ta:.3f} s "
                                      f"at {tdrop:.2f} s: a locked wheel, odometry ignored while it lasts")
            i = bisect.bisect_right(ts, tb - self.span + 1e-9) - 1
            if i < 0:
                continue
            ta, va = ts[i], abs(speeds[i][1])
            if tb > ta and vb < va and (va - vb) / (tb - ta) > self.decel:
                until = tb + va / self.stop_accel
                if self.since is None:
                    self.since, self.until, self.floor, self.confirmed = tb, until, vb, False
                    self.drop = (ta, va, tb, vb)
                else:
                    self.until, self.floor = max(self.until, until), min(self.floor, vb)
        if self.since is not None and t0 >= self.until:
            self.since = None  # the vehicle has long stopped: the wheel's standstill is its own
        return self.since is not None and self.confirmed, events


class DeadWheel:
    """A wheel-speed channel that reads 0 while the vehicle moves: the wheel says standstill
    while the bias-corrected gyro says the vehicle turns faster than ``check_rate`` for
    ``check_time`` s (an Ackermann vehicle cannot turn in place). The fault holds while the
    wheel reads standstill (below ``rest_speed``); ``since`` is its start, None without one.
    One :meth:`update` per keyframe interval of ``dt`` s.

    A full brake in a turn locks the wheel while the vehicle slides on, turning: the check
    then finds a "dead" channel during the lock, and held it for as long as the braked
    vehicle stood (15 s of "reads 0 while the vehicle moves" in /diagnostics, and no
    odometry, after a protective stop in a curve). So a fault found during a wheel lock
    ends with the lock (``lock_until``: when the vehicle must have stopped) if the gyro
    then says the vehicle no longer turns: the wheel's standstill is the vehicle's, as the
    lock itself concludes. A channel that died at speed first reads as a lock too; the
    vehicle still turning when the lock ends keeps it dead (a dead channel on a straight
    line is beyond this check either way)."""

    def __init__(self, check_rate: float, check_time: float, rest_speed: float, dt: float) -> None:
        self.check_rate, self.check_time, self.rest_speed, self.dt = check_rate, check_time, rest_speed, dt
        self.suspect = 0.0  # [s] the wheel read 0 while the gyro said the vehicle turned
        self.since: Optional[float] = None
        self.lock_until: Optional[float] = None  # found during a wheel lock: when that lock ends

    def update(self, t: float, max_speed: float, yaw_rate: Optional[float],
               lock_until: Optional[float] = None) -> Tuple[bool, bool, List[str]]:
        """``max_speed``: the largest wheel speed magnitude in the interval ending at ``t``;
        ``yaw_rate``: the gyro's bias-corrected yaw rate over it (None: unknown);
        ``lock_until``: with a wheel lock going on, when it ends. Returns (dead, just
        began, events to log)."""
        if max_speed >= self.rest_speed or self.check_time <= 0.0:
            self.suspect = 0.0
            events = [] if self.since is None else [f"wheel speed back at {t:.2f} s after {t - self.since:.1f} s "
                                                    "reading 0 while moving"]
            self.since = self.lock_until = None
            return False, False, events
        if self.since is not None:
            if (self.lock_until is not None and t >= self.lock_until and yaw_rate is not None
                    and abs(yaw_rate) <= self.check_rate):
                since, self.since, self.lock_until, self.suspect = self.since, None, None, 0.0
                return False, False, [f"wheel speed reads 0 and the gyro no turn at {t:.2f} s, after the locked "
                                      f"wheel's slide (0 since {since:.2f} s): the vehicle stands, odometry used again"]
            return True, False, []
        if yaw_rate is not None and abs(yaw_rate) > self.check_rate:
            self.suspect += self.dt
        else:
            self.suspect = 0.0
        if self.suspect >= self.check_time - 1e-9:
            self.since = t
            self.lock_until = lock_until
            return True, True, [f"wheel speed reads 0 at {t:.2f} s while the gyro says the vehicle turns: "
                                "odometry ignored until it reads motion again"]
        return False, False, []
