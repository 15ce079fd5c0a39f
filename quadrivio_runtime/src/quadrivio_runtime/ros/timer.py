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
from typing import Callable, List, Optional, Tuple

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy

from quadrivio_runtime.guards import InputGuard


def guarded_timer(period: float, callback: Callable[[rospy.timer.TimerEvent], None], what: str,
                  inline: bool = False):
    """``rospy.Timer(rospy.Duration(period), callback)`` whose exceptions are logged, not
    fatal, and which goes on after /clock jumps back. In lockstep (a member that called
    ``lockstep.install()``) it runs in the simulator's rounds instead, at the multiples of
    ``period`` in sim time.

    ``inline``: in sim time, call it in the thread that receives /clock instead of a thread
    of its own (:class:`InlineTimer`: no thread wake-up per period; for short callbacks
    that must not block, as they delay every other sim-time timer of the process)."""

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
    if not rospy.rostime.is_wallclock():
        return InlineTimer(period, run, _beat()) if inline else SimTimer(period, run, _beat())
    return rospy.Timer(rospy.Duration(period), run, reset=True)


class SimBeat:
    """Wakes sim-time timers when they are due, not on every /clock tick.

    rospy wakes every thread sleeping in sim time on every /clock message (one
    ``notify_all`` on one condition): a process with a 1 Hz diagnostics timer, a 20 Hz
    cycle and a 50 Hz one woke three threads 100 times per simulated second, and the
    wake-ups were a fifth to a third of its Python time (py-spy, the figure eight). The
    beat sets each timer's event when its time has come, or when time moved back (the
    timer starts its period again, as rospy's ``reset=True``); each timer keeps a thread of
    its own, so one slow callback delays no other. In a node (``on_clock``) the beat runs
    in the thread that receives /clock, as one more callback of rospy's own subscription
    (rospy shares one per topic and process, and calls its callbacks in order: the time is
    set first), so a tick wakes no thread that has nothing due; otherwise (a test's clock)
    a thread of its own waits on rospy's condition."""

    def __init__(self, now: Callable[[], int] = lambda: rospy.rostime.get_rostime().to_nsec(),
                 cond: Optional[threading.Condition] = None, on_clock: bool = False) -> None:
        self.now = now
        self.cond = cond if cond is not None else rospy.rostime.get_rostime_cond()
        self.on_clock = on_clock
        self.lock = threading.Lock()
        self.waiting: List[list] = []  # [due_ns, event, ROS time when it began to wait]
        self.inline: List["InlineTimer"] = []
        self.thread: Optional[threading.Thread] = None
        self.started = False
        self.closed = False

    def wait(self, due_ns: int, stop: Callable[[], bool], since_ns: Optional[int] = None) -> int:
        """Block until ROS time reaches ``due_ns`` or moves back (or ``stop()``); the time then.
        ``since_ns``: the time ``due_ns`` was scheduled at: time below it has moved back,
        also when it moved while the caller was not waiting yet (its callback running). A
        timer that took the time when it began to wait missed such a jump, and slept until
        the time before the reset came round again (the localization after a reset under
        load: 89 s without an estimate, faults.test)."""
        event = threading.Event()
        with self.lock:
            now = self.now()
            since = now if since_ns is None else min(since_ns, now)
            if now >= due_ns or self.closed or (since_ns is not None and now < since_ns):
                return now
            self.waiting.append([due_ns, event, since])
            self._start()
        while not event.wait(0.5):
            if stop():
                break
        return self.now()

    def add_inline(self, timer: "InlineTimer") -> None:
        with self.lock:
            self.inline.append(timer)
            self._start()

    def _start(self) -> None:  # under self.lock
        if self.started:
            return
        self.started = True
        if self.on_clock:
            from rosgraph_msgs.msg import Clock
            rospy.Subscriber("/clock", Clock, lambda _m: self.tick(self.now()), queue_size=1)
        else:
            self.thread = threading.Thread(target=self._loop, name="sim_beat", daemon=True)
            self.thread.start()

    def tick(self, now: int) -> None:
        """Release the waiters that are due at ``now``, and all of them if time moved back;
        then run the inline timers that are due."""
        with self.lock:
            due = [w for w in self.waiting if now >= w[0] or now < w[2]]
            self.waiting = [w for w in self.waiting if not (now >= w[0] or now < w[2])]
            inline = list(self.inline)
        for w in due:
            w[1].set()
        for timer in inline:
            timer.tick(now)

    def close(self) -> None:
        """Stop the thread and release every waiter."""
        self.closed = True
        with self.cond:
            self.cond.notify_all()

    def _loop(self) -> None:
        seen = None
        while not (self.closed or rospy.core.is_shutdown_requested()):
            with self.cond:
                while self.now() == seen and not (self.closed or rospy.core.is_shutdown_requested()):
                    self.cond.wait(0.5)
                seen = self.now()
            self.tick(seen)
            if rospy.rostime.is_wallclock():  # no /clock any more (a test): wall time never stops moving
                with self.cond:
                    self.cond.wait(0.01)
        with self.lock:
            waiting, self.waiting = self.waiting, []
        for w in waiting:
            w[1].set()


class SimTimer:
    """A sim-time timer on :class:`SimBeat`: calls ``callback(None)`` every ``period`` of ROS
    time (a period behind by more than two starts again from now, as rospy.Rate), and
    starts its period again when time moves back."""

    def __init__(self, period: float, callback: Callable, beat: SimBeat) -> None:
        self.period_ns = int(round(period * 1e9))
        self.callback, self.beat = callback, beat
        self._shutdown = False
        self.thread = threading.Thread(target=self._run, name="sim_timer", daemon=True)
        self.thread.start()

    def shutdown(self) -> None:
        self._shutdown = True

    def join(self, timeout: Optional[float] = None) -> None:
        self.thread.join(timeout)

    def is_alive(self) -> bool:
        return self.thread.is_alive()

    def _stopped(self) -> bool:
        return self._shutdown or rospy.core.is_shutdown_requested()

    def _run(self) -> None:
        seen = self.beat.now()  # the time the next due was scheduled at
        due = seen + self.period_ns
        while not self._stopped():
            now = self.beat.wait(due, self._stopped, seen)  # may wake early (its 0.5 s wait)
            if self._stopped() or self.beat.closed:
                return
            fire, due = _schedule(due, now, self.period_ns)
            seen = now
            if fire:
                self.callback(None)


def _schedule(due: int, now: int, period: int) -> Tuple[bool, int]:
    """A sim-time timer's schedule at ROS time ``now``: whether it fires, and when it is
    due next. Every ``period``; a new period from now when time moved back, or when the
    timer fell more than two periods behind (no burst to catch up, as rospy.Rate)."""
    if now < due - period:  # time moved back
        return False, now + period
    if now < due:
        return False, due
    due += period
    return True, (now + period if now - due > 2 * period else due)


class InlineTimer:
    """A sim-time timer called by :class:`SimBeat` in the thread that delivers the clock
    ticks (in a node, rospy's /clock subscriber thread), with :class:`SimTimer`'s schedule:
    ``callback(None)`` every ``period`` of ROS time, a new period from now when time moves
    back or the timer falls more than two periods behind. It costs no thread wake-up per
    period; the callback delays the process's other sim-time timers while it runs."""

    def __init__(self, period: float, callback: Callable, beat: SimBeat) -> None:
        self.period_ns = int(round(period * 1e9))
        self.callback, self.beat = callback, beat
        self._shutdown = False
        self.due = beat.now() + self.period_ns
        beat.add_inline(self)

    def shutdown(self) -> None:
        self._shutdown = True

    def is_alive(self) -> bool:
        return not (self._shutdown or self.beat.closed)

    def tick(self, now: int) -> None:
        if self._shutdown or rospy.core.is_shutdown_requested():
            return
        fire, self.due = _schedule(self.due, now, self.period_ns)
        if fire:
            self.callback(None)


_BEAT: Optional[SimBeat] = None
_BEAT_LOCK = threading.Lock()


def _beat() -> SimBeat:
    global _BEAT
    with _BEAT_LOCK:
        if _BEAT is None:
            _BEAT = SimBeat(on_clock=rospy.core.is_initialized())
        return _BEAT


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
        """True (after running the hooks) when time moved back since the last check.

        The time is read with the lock held: read outside it, a thread descheduled between
        its read and the comparison (30 ms at factor 2 on two loaded cores) compared an old
        reading with the newer one another thread had stored meanwhile, and a follower that
        saw time "move back" by 30 ms reset itself to the start of its path and aborted."""
        with self.lock:
            now = self._read()
            if now is None:
                return False
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
    return _unless_shutting_down(pub.publish, msg)


def send_transform(broadcaster, transform) -> bool:
    """``broadcaster.sendTransform(transform)`` (a tf2_ros broadcaster), as :func:`publish`."""
    return _unless_shutting_down(broadcaster.sendTransform, transform)


def _unless_shutting_down(send: Callable[[object], None], msg) -> bool:
    try:
        send(msg)
        return True
    except rospy.ROSException:
        if not rospy.core.is_shutdown_requested():
            raise
        return False
