"""States stamped when the PLC measured them: a backlog read late keeps its age."""
import numpy as np
import pytest

from quadrivio_plc.client import PlcClock

RATE = 50.0


def test_a_backlog_read_after_a_freeze_keeps_its_measurement_times():
    """50 Hz states with 1-5 ms of transport delay on a PLC clock of another epoch; the
    client is stopped for 5 s and then reads the 1 s of states the socket kept at once."""
    rng = np.random.default_rng(1)
    clock = PlcClock()
    epoch = 12345.678  # the PLC's clock starts elsewhere
    stamps, truth = [], []
    for k in range(500):  # 10 s of normal reception
        t = k / RATE
        stamps.append(clock.stamp(epoch + t, t + rng.uniform(0.001, 0.005)))
        truth.append(t)
    freeze_end = 14.9  # (read before the next fresh state)
    for k in range(500, 550):  # measured 10-11 s, all read at 15 s
        t = k / RATE
        stamps.append(clock.stamp(epoch + t, freeze_end + 1e-4 * (k - 500)))
        truth.append(t)
    for k in range(750, 800):  # fresh again
        t = k / RATE
        stamps.append(clock.stamp(epoch + t, t + rng.uniform(0.001, 0.005)))
        truth.append(t)
    err = np.array(stamps) - np.array(truth)
    assert np.all(err >= 0.0) and np.max(err[500:]) < 0.006  # the backlog is stamped 10-11 s, not 14.9 s
    assert np.all(np.diff(stamps) > 0)  # in order
    assert clock.late == 50 and clock.restarts == 0


def test_a_slow_plc_clock_is_followed_and_a_restart_starts_over():
    clock = PlcClock()
    ratio = 1.0 - 5e-5  # the PLC's clock runs 50 ppm slow
    for k in range(3000):  # 60 s
        t = k / RATE
        s = clock.stamp(100.0 + ratio * t, t + 0.002)
        assert t <= s <= t + 0.002 + 1e-9
    # the PLC restarts: its clock begins again at 0
    s = clock.stamp(0.0, 60.5)
    assert clock.restarts == 1 and s == pytest.approx(60.5)
    assert clock.stamp(1.0, 61.5 + 0.002) == pytest.approx(61.5, abs=1e-3)
    # and the receiver's clock moving back (the simulator's reset) too
    clock.stamp(2.0, 0.5)
    assert clock.restarts == 2


def test_stamps_never_lie_ahead_of_receipt_or_fail_on_nan():
    clock = PlcClock()
    assert clock.stamp(10.0, 5.0) == 5.0
    assert clock.stamp(10.02, 5.001) <= 5.001  # a frame faster than the first: offset shrinks
    assert clock.stamp(float("nan"), 5.1) == 5.1
