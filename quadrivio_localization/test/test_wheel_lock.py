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
