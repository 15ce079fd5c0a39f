"""The dead wheel-speed channel check (quadrivio_localization.wheel_lock.DeadWheel); the
locked wheel is tested through the smoother (test_smoother.py)."""
import pytest


def test_a_dead_wheel_channel_is_named_after_its_check_time_and_cleared_by_motion():
    """DeadWheel: the wheel reads 0 while the gyro turns faster than check_rate; after
    check_time it is dead (once: 'just began'), until the wheel reads motion again."""
    from quadrivio_localization.wheel_lock import DeadWheel

    d = DeadWheel(check_rate=0.05, check_time=1.0, rest_speed=0.05, dt=0.05)
    t, out = 0.0, []
    for _ in range(30):  # 1.5 s at 20 Hz: wheel 0, turning at 0.3 rad/s
        t += 0.05
        out.append(d.update(t, 0.0, 0.3))
    began = [k for k, (dead, b, _) in enumerate(out) if b]
    assert len(began) == 1 and abs((began[0] + 1) * 0.05 - 1.0) < 1e-9  # after exactly check_time
    assert all(dead for dead, _, _ in out[began[0]:]) and not any(dead for dead, _, _ in out[:began[0]])
    assert "reads 0 at 1.00 s" in out[began[0]][2][0] and d.since == pytest.approx(1.0)
    dead, b, events = d.update(t + 0.05, 1.2, 0.3)  # the wheel turns again
    assert not dead and not b and "back at" in events[0] and d.since is None
    # standing still (no yaw rate), or a yaw rate below check_rate, or an unknown one: never dead
    for rate in (0.0, 0.04, None):
        d = DeadWheel(0.05, 1.0, 0.05, 0.05)
        assert not any(d.update(0.05 * k, 0.0, rate)[0] for k in range(1, 100))
    # check_time 0: the check is off
    d = DeadWheel(0.05, 0.0, 0.05, 0.05)
    assert not any(d.update(0.05 * k, 0.0, 1.0)[0] for k in range(1, 100))


def test_a_dead_channel_found_in_a_locked_wheels_slide_ends_with_the_lock_once_the_vehicle_stops_turning():
    """A full brake in a turn: the wheel locks and reads 0 while the vehicle slides on,
    turning, so the check finds a "dead" channel during the lock. Once the lock ends (the
    vehicle must have stopped) with the gyro quiet, the wheel's standstill is the vehicle's:
    not dead. Still turning then, or found outside any lock, it stays dead until the wheel
    reads motion."""
    from quadrivio_localization.wheel_lock import DeadWheel

    def drive(lock_until, rates):
        d, out = DeadWheel(check_rate=0.05, check_time=0.3, rest_speed=0.05, dt=0.05), []
        for k, rate in enumerate(rates):
            out.append(d.update(0.05 * (k + 1), 0.0, rate, lock_until))
        return d, out

    slide = [0.3] * 8 + [0.0] * 40  # turning for 0.4 s, then standing
    d, out = drive(1.0, slide)
    dead = [x for x, _, _ in out]
    assert dead[5] and sum(b for _, b, _ in out) == 1  # found in the slide (after check_time)...
    assert not any(dead[19:]) and all(dead[5:19])  # ...and over when the lock ends, at 1.0 s
    ended = [e for _, _, ev in out for e in ev if "odometry used again" in e]
    assert len(ended) == 1 and "at 1.00 s" in ended[0] and d.since is None
    # no new fault while it stands: the gyro is quiet
    assert d.update(5.0, 0.0, 0.0, None) == (False, False, [])
    # still turning when the lock ends (a channel that died at speed): dead until motion
    d, out = drive(1.0, [0.3] * 48)
    assert all(x for x, _, _ in out[5:]) and d.since is not None
    # found with no lock going on (a braked vehicle pushed round): dead while it stands
    d, out = drive(None, slide)
    assert all(x for x, _, _ in out[5:]) and d.since is not None
    # the gyro unknown when the lock ends: kept (nothing says it stopped turning)
    d, out = drive(1.0, [0.3] * 8 + [None] * 40)
    assert all(x for x, _, _ in out[5:])
    # the wheel turning again ends the fault as before, whatever the lock
    d, _ = drive(10.0, [0.3] * 10)
    dead, began, events = d.update(0.6, 1.0, 0.3, 10.0)
    assert not dead and "back at" in events[0] and d.lock_until is None
