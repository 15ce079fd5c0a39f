"""Periodic work, publishing and input checks that survive exceptions, shutdown and
clock jumps.

rospy runs each Timer in its own thread and that thread ends on the first exception the
callback raises, including the ``ROSTimeMovedBackwardsException`` its sleep raises when
/clock jumps back (the simulator's ``~reset``, a bag played in a loop): the node keeps
running, silently without its periodic work (a localization that stops publishing, a
follower that stops steering). ``guarded_timer`` logs the callback's exceptions with
their traceback (throttled), and restarts its period when time moves back.

:func:`on_clock_jump` registers what a node must forget when time moves back (filters,
queues, histories): one watcher thread per process notices the jump within
``ClockWatch.POLL`` wall seconds, and any callback can notice it sooner with
:func:`check_clock`. Each hook runs once per jump.
"""

from __future__ import annotations

import threading
import traceback
from typing import Callable, List, Optional

import rospy

from ..guards import InputGuard


def guarded_timer(period: float, callback: Callable[[rospy.timer.TimerEvent], None], what: str):
    """``rospy.Timer(rospy.Duration(period), callback)`` whose exceptions are logged, not
    fatal, and which goes on after /clock jumps back. In lockstep (a member that called
    ``lockstep.install()``) it runs in the simulator's rounds instead, at the multiples of
    ``period`` in sim time."""

    def run(event) -> None:
        check_clock()
        try:
            callback(event)
        except Exception:  # noqa: BLE001 - one failed cycle must not end the periodic work
            if rospy.core.is_shutdown_requested():  # publishers close before is_shutdown()
                return
            rospy.logerr_throttle(5.0, "%s failed (retrying every cycle):\n%s", what, traceback.format_exc())

    from . import lockstep

    m = lockstep.member()
    if m is not None:  # run in the simulator's rounds (see lockstep.py), not on a thread
        return m.add_timer(period, run)
    return rospy.Timer(rospy.Duration(period), run, reset=True)


class ClockWatch:
    """Notices ROS time moving back and calls the registered hooks once per jump."""

    POLL = 0.05  # [s wall]

    def __init__(self, now: Callable[[], float] = lambda: rospy.get_time()) -> None:
        self.now = now
        self.hooks: List[Callable[[float, float], None]] = []
        self.lock = threading.Lock()
        self.last: Optional[float] = None
        self.jumps = 0
        self.thread: Optional[threading.Thread] = None

    def add(self, hook: Callable[[float, float], None]) -> None:
        with self.lock:
            self.hooks.append(hook)
            if self.last is None:
                self.last = self._read()

    def _read(self) -> Optional[float]:
        try:
            return self.now()
        except Exception:  # noqa: BLE001 - before init_node, or at shutdown
            return None

    def check(self) -> bool:
        """True (after running the hooks) when time moved back since the last check."""
        now = self._read()
        if now is None:
            return False
        with self.lock:
            before, jumped = self.last, self.last is not None and now < self.last
            self.last = now
            if not jumped:
                return False
            self.jumps += 1
            hooks = list(self.hooks)
        rospy.logwarn("ROS time moved back from %.3f s to %.3f s: resetting this node's state", before, now)
        for hook in hooks:
            try:
                hook(before, now)
            except Exception:  # noqa: BLE001 - one failed hook must not skip the others
                rospy.logerr("reset after the clock jump failed:\n%s", traceback.format_exc())
        return True

    def start(self) -> None:
        if self.thread is not None:
            return

        def loop() -> None:
            stop = threading.Event()
            while not rospy.core.is_shutdown_requested():
                self.check()
                stop.wait(self.POLL)

        self.thread = threading.Thread(target=loop, name="clock_watch", daemon=True)
        self.thread.start()


_WATCH = ClockWatch()


def on_clock_jump(hook: Callable[[float, float], None]) -> None:
    """Call ``hook(before, now)`` whenever ROS time moves back (reset, bag loop)."""
    _WATCH.add(hook)
    _WATCH.start()


def check_clock() -> bool:
    """Check for a backwards jump now (runs the hooks); cheap enough for every callback."""
    return _WATCH.check()


def input_guard(max_future: float = 0.5, max_age: float = float("inf")) -> InputGuard:
    """An :class:`InputGuard` whose rejects are logged (throttled to one line per 5 s)."""
    return InputGuard(max_future, max_age, log=lambda text: rospy.logwarn_throttle(5.0, text))


def publish(pub: rospy.Publisher, msg) -> bool:
    """``pub.publish(msg)``; False instead of an exception once the node is shutting down
    (rospy closes publishers before ``is_shutdown()`` turns true)."""
    try:
        pub.publish(msg)
        return True
    except rospy.ROSException:
        if not rospy.core.is_shutdown_requested():
            raise
        return False
