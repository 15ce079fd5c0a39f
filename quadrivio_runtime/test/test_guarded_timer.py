"""guarded_timer: a callback that raises keeps being called (rospy.Timer's thread would
end), and so does one whose clock jumps back; the clock watcher runs the reset hooks."""

import threading
import time

import pytest
import rospy
import rospy.rostime

from quadrivio_runtime.ros import timer as T
from quadrivio_runtime.ros.timer import guarded_timer

pytestmark = pytest.mark.wall  # timer rates against the wall clock (pytest.ini)


def wait(cond, timeout=5.0):
    done = threading.Event()
    deadline = threading.Event()
    t = threading.Timer(timeout, deadline.set)
    t.start()
    try:
        while not cond():
            assert not deadline.is_set(), "timed out"
            done.wait(0.002)
    finally:
        t.cancel()


@pytest.fixture
def wall_time():
    rospy.rostime.set_rostime_initialized(True)  # wall time, no master needed
    yield
    rospy.rostime._rostime_current = None


@pytest.fixture
def sim_time():
    """A hand-driven sim clock, as /clock would set it."""
    rospy.rostime.set_rostime_initialized(True)
    clock = {"t": 100.0}

    def set_time(t):
        clock["t"] = t
        rospy.rostime._set_rostime(rospy.Time.from_sec(t))
    set_time(100.0)
    stop = threading.Event()

    def tick():  # 1 ms of sim time every 0.2 ms of wall time, like a fast simulator
        while not stop.is_set():
            set_time(clock["t"] + 0.001)
            stop.wait(0.0002)
    th = threading.Thread(target=tick, daemon=True)
    th.start()
    yield set_time
    stop.set()
    th.join()
    if T._BEAT is not None:  # this clock's beat ends with it
        T._BEAT.close()
        T._BEAT = None
    rospy.rostime._rostime_current = None


def test_a_raising_callback_keeps_its_timer_alive(monkeypatch, wall_time):
    logged = []
    monkeypatch.setattr(rospy, "logerr_throttle", lambda period, fmt, *args: logged.append(fmt % args))
    calls = []

    def callback(_event):
        calls.append(1)
        raise ValueError("bad sample")

    timer = guarded_timer(0.01, callback, "test cycle")
    try:
        wait(lambda: len(calls) >= 5)
    finally:
        timer.shutdown()
        timer.join(5.0)
    assert not timer.is_alive()
    assert logged and "test cycle failed" in logged[0] and "ValueError: bad sample" in logged[0]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_plain_rospy_timer_dies_on_the_first_exception(wall_time):
    """The behaviour guarded_timer exists for: if rospy ever changes it, guarded_timer can go."""
    calls = []

    def callback(_event):
        calls.append(1)
        raise ValueError("bad sample")

    timer = rospy.Timer(rospy.Duration(0.01), callback)
    timer.join(5.0)  # the thread ends by itself, on the exception
    assert not timer.is_alive() and len(calls) == 1


def test_the_timer_goes_on_and_the_hooks_run_when_the_clock_moves_back(monkeypatch, sim_time):
    monkeypatch.setattr(rospy, "logwarn", lambda *a: None)
    watch = T.ClockWatch()
    monkeypatch.setattr(T, "_WATCH", watch)
    jumps = []
    T.on_clock_jump(lambda before, now: jumps.append((before, now)))
    calls = []
    timer = guarded_timer(0.01, lambda e: calls.append(rospy.get_time()), "test cycle")
    try:
        wait(lambda: len(calls) >= 5)
        sim_time(1.0)  # the simulator's ~reset
        wait(lambda: jumps and any(t < 50.0 for t in calls[-3:]))
        n = len(calls)
        wait(lambda: len(calls) >= n + 5)  # and it keeps its period after the jump
    finally:
        timer.shutdown()
        timer.join(5.0)
    assert len(jumps) == 1 and jumps[0][0] > 99.0 and jumps[0][1] < 50.0
    assert watch.jumps == 1


def test_a_hook_that_fails_does_not_stop_the_others(monkeypatch, wall_time):
    monkeypatch.setattr(rospy, "logwarn", lambda *a: None)
    monkeypatch.setattr(rospy, "logerr", lambda *a: None)
    now = [10.0]
    watch = T.ClockWatch(now=lambda: now[0])
    ran = []
    watch.add(lambda b, n: 1 / 0)
    watch.add(lambda b, n: ran.append((b, n)))
    assert not watch.check()
    now[0] = 11.0
    assert not watch.check()
    now[0] = 2.0
    assert watch.check() and ran == [(11.0, 2.0)]
    assert not watch.check()  # once per jump


def test_a_reader_descheduled_between_reading_and_comparing_sees_no_jump(monkeypatch):
    """Two threads check at once; the first is descheduled right after reading the time
    (A reads 1.0, B reads 2.0 and stores it, A then compares). Read outside the lock, A's
    old reading was taken for time moving back (a follower reset itself mid-path)."""
    monkeypatch.setattr(rospy, "logwarn", lambda *a: None)
    clock = {"t": 0.0}
    a_read = threading.Event()
    b_done = threading.Event()

    def now():
        clock["t"] += 1.0
        t = clock["t"]
        if threading.current_thread().name == "A":
            a_read.set()
            b_done.wait(0.3)  # descheduled: B runs meanwhile, if it can
        return t

    watch = T.ClockWatch(now=now)
    jumps = []
    watch.hooks.append(lambda before, after: jumps.append((before, after)))

    def b_check():
        a_read.wait(2.0)
        watch.check()
        b_done.set()

    a = threading.Thread(target=watch.check, name="A")
    b = threading.Thread(target=b_check, name="B")
    a.start()
    b.start()
    a.join(5.0)
    b.join(5.0)
    assert jumps == [] and watch.jumps == 0
    assert watch.last == 2.0


def test_in_sim_time_a_timer_wakes_when_due_not_on_every_tick():
    """SimBeat releases a waiter only once ROS time reaches its time, or moves back."""
    now = [int(10e9)]
    beat = T.SimBeat(now=lambda: now[0], cond=threading.Condition())
    results = {}

    def waiter(name, due):
        results[name] = beat.wait(due, lambda: False)
    a = threading.Thread(target=waiter, args=("a", int(11e9)))
    b = threading.Thread(target=waiter, args=("b", int(12e9)))
    a.start(), b.start()
    wait(lambda: len(beat.waiting) == 2)
    for t in (10.01, 10.5, 10.99):  # ticks before either is due release nothing
        now[0] = int(t * 1e9)
        beat.tick(now[0])
    assert len(beat.waiting) == 2 and not results
    now[0] = int(11e9)
    beat.tick(now[0])
    a.join(5.0)
    assert results == {"a": int(11e9)} and len(beat.waiting) == 1
    now[0] = int(3e9)  # time moves back (a reset): the other one is released too
    beat.tick(now[0])
    b.join(5.0)
    assert results["b"] == int(3e9) and not beat.waiting


def test_a_sim_time_timer_keeps_its_period_and_a_slow_one_delays_no_other(sim_time):
    """Two timers on one beat: a 10 ms one keeps its rate of sim time while a 50 ms one
    sleeps inside its callback (its own thread)."""
    fast, slow = [], []
    block = threading.Event()

    def slow_cb(_e):
        slow.append(rospy.get_time())
        block.wait(0.2)  # wall seconds: many ticks of the fast timer
    t1 = guarded_timer(0.01, lambda e: fast.append(rospy.get_time()), "fast")
    t2 = guarded_timer(0.05, slow_cb, "slow")
    assert isinstance(t1, T.SimTimer)
    try:
        wait(lambda: len(slow) >= 1 and len(fast) >= 60)
        inside = [t for t in fast if t > slow[0]]
        assert len(inside) >= 20  # the fast timer ran while the slow callback waited
        rate = (len(fast) - 1) / (fast[-1] - fast[0])  # per second of sim time
        assert 50.0 < rate < 105.0, rate  # 100 (fewer only if it fell two periods behind)
    finally:
        block.set()
        for t in (t1, t2):
            t.shutdown()
            t.join(5.0)
    assert not t1.is_alive() and not t2.is_alive()


def test_an_inline_timer_runs_in_the_ticking_thread_on_its_schedule():
    """InlineTimer: called by the beat's tick itself (no thread of its own) at the
    multiples of its period, a new period after time moves back or falls far behind."""
    now = [int(10e9)]
    beat = T.SimBeat(now=lambda: now[0], cond=threading.Condition())
    beat.started = True  # ticks come from this test, not from /clock or the beat's thread
    calls = []
    timer = T.InlineTimer(0.05, lambda _e: calls.append((now[0], threading.current_thread())), beat)
    for k in range(1, 21):  # 10 ms ticks for 0.2 s
        now[0] = int(10e9) + k * int(10e6)
        beat.tick(now[0])
    assert [c[0] for c in calls] == [int(10.05e9), int(10.10e9), int(10.15e9), int(10.20e9)]
    assert {c[1] for c in calls} == {threading.current_thread()}
    now[0] = int(3e9)  # time moves back: no call now, then every 50 ms from there
    beat.tick(now[0])
    assert len(calls) == 4
    now[0] = int(3.04e9)
    beat.tick(now[0])
    now[0] = int(3.05e9)
    beat.tick(now[0])
    assert calls[-1][0] == int(3.05e9) and len(calls) == 5
    now[0] = int(9e9)  # far behind: one call, then a period from now (no burst)
    beat.tick(now[0])
    beat.tick(now[0])
    now[0] = int(9.04e9)
    beat.tick(now[0])
    assert [c[0] for c in calls[5:]] == [int(9e9)]
    timer.shutdown()
    now[0] = int(9.2e9)
    beat.tick(now[0])
    assert len(calls) == 6 and not timer.is_alive()


def test_guarded_timer_inline_in_sim_time(sim_time):
    got = []
    t = guarded_timer(0.01, lambda e: got.append(rospy.get_time()), "inline", inline=True)
    assert isinstance(t, T.InlineTimer)
    try:
        wait(lambda: len(got) >= 30)
        rate = (len(got) - 1) / (got[-1] - got[0])
        assert 50.0 < rate < 105.0, rate
    finally:
        t.shutdown()


def test_a_sim_time_timer_busy_when_the_clock_moves_back_starts_its_period_again():
    """The clock moves back (a reset) while the timer's callback runs: when the callback
    returns, the timer waits one period of the new time, not until the time before the
    reset comes round again (the localization's cycle, busy at the reset under load, gave
    no estimate for 89 s of sim time)."""
    now = [int(89.2e9)]
    beat = T.SimBeat(now=lambda: now[0], cond=threading.Condition())
    calls, inside, release = [], threading.Event(), threading.Event()

    def cb(_e):
        calls.append(now[0])
        if len(calls) == 1:
            inside.set()
            release.wait(5.0)
    timer = T.SimTimer(0.05, cb, beat)
    try:
        now[0] = int(89.25e9)
        beat.tick(now[0])
        assert inside.wait(5.0)  # the first call runs ...
        now[0] = int(0.01e9)  # ... when the clock moves back
        beat.tick(now[0])
        release.set()
        wait(lambda: len(beat.waiting) == 1)  # the timer waits again, on the new time
        for k in range(2, 31):  # 10 ms ticks up to 0.3 s
            now[0] = int(k * 0.01e9)
            beat.tick(now[0])
            time.sleep(0.002)
        wait(lambda: len(calls) >= 5)
        after = [c / 1e9 for c in calls[1:]]
        assert after[0] <= 0.07, after  # one period after the jump, not at 89.3 s
        assert all(b - a == pytest.approx(0.05, abs=0.011) for a, b in zip(after, after[1:])), after
    finally:
        release.set()
        timer.shutdown()
        beat.close()


class _Closed:
    """A publisher or tf2_ros broadcaster whose topic rospy has closed."""

    def __init__(self):
        self.sent = 0

    def _send(self, msg):
        self.sent += 1
        raise rospy.ROSException("publish() to a closed topic")

    publish = sendTransform = _send


@pytest.mark.parametrize("send", [T.publish, T.send_transform])
def test_a_send_to_a_closed_topic_during_shutdown_is_false_and_otherwise_raises(send, monkeypatch):
    closed = _Closed()
    monkeypatch.setattr(rospy.core, "is_shutdown_requested", lambda: False)
    with pytest.raises(rospy.ROSException, match="closed topic"):
        send(closed, object())
    monkeypatch.setattr(rospy.core, "is_shutdown_requested", lambda: True)
    assert send(closed, object()) is False
    assert closed.sent == 2


class _Open:
    def __init__(self):
        self.sent = []

    def publish(self, msg):
        self.sent.append(msg)

    sendTransform = publish


@pytest.mark.parametrize("send", [T.publish, T.send_transform])
def test_a_send_to_an_open_topic_is_true(send):
    open_ = _Open()
    assert send(open_, "m") is True and open_.sent == ["m"]
