"""guarded_timer: a callback that raises keeps being called (rospy.Timer's thread would end)."""

import threading
import time

import pytest
import rospy
import rospy.rostime

from quadrivio_description.ros.timer import guarded_timer


def test_a_raising_callback_keeps_its_timer_alive(monkeypatch):
    rospy.rostime.set_rostime_initialized(True)  # wall time, no master needed
    logged = []
    monkeypatch.setattr(rospy, "logerr_throttle", lambda period, fmt, *args: logged.append(fmt % args))
    calls = []
    done = threading.Event()

    def callback(_event):
        calls.append(1)
        if len(calls) >= 5:
            done.set()
        raise ValueError("bad sample")

    timer = guarded_timer(0.01, callback, "test cycle")
    try:
        assert done.wait(5.0), f"the timer stopped after {len(calls)} call(s)"
    finally:
        timer.shutdown()
        time.sleep(0.05)
    assert len(calls) >= 5
    assert logged and "test cycle failed" in logged[0] and "ValueError: bad sample" in logged[0]


@pytest.mark.filterwarnings("ignore::pytest.PytestUnhandledThreadExceptionWarning")
def test_plain_rospy_timer_dies_on_the_first_exception():
    """The behaviour guarded_timer exists for: if rospy ever changes it, guarded_timer can go."""
    rospy.rostime.set_rostime_initialized(True)
    calls = []

    def callback(_event):
        calls.append(1)
        raise ValueError("bad sample")

    timer = rospy.Timer(rospy.Duration(0.01), callback)
    time.sleep(0.3)
    timer.shutdown()
    assert len(calls) == 1
