"""guarded_timer: a callback that raises keeps being called (rospy.Timer's thread would
end), and so does one whose clock jumps back; the clock watcher runs the reset hooks."""

import threading

import pytest
import rospy
import rospy.rostime

from quadrivio_description.ros import timer as T
from quadrivio_description.ros.timer import guarded_timer


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
