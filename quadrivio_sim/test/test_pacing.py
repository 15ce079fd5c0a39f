"""Pacer: waits when ahead, makes up a short lag, drops a long one."""
import pytest

from quadrivio_sim.pacing import LoopHold, Pacer, StaleSlowdown


def run(pacer, steps, dt, cost, stall_at=None, stall=0.0):
    """Simulate a stepping loop whose steps cost ``cost`` wall seconds; returns the wall
    time of each step's start."""
    wall, t, starts = 0.0, 0.0, []
    pacer.anchor(t, wall)
    for i in range(steps):
        starts.append((t, wall))
        wall += cost + (stall if i == stall_at else 0.0)
        t += dt
        wall += pacer.wait(t, wall)
    return starts


def periods_after(starts, i):
    """Wall time between consecutive step starts after step ``i``."""
    after = starts[i + 1:]
    return [wb - wa for (_, wa), (_, wb) in zip(after, after[1:])]


@pytest.mark.parametrize("stall", [0.0, 0.02])  # none; 40 ms of sim time late at factor 2
def test_paces_at_the_factor_and_makes_up_a_short_lag(stall):
    p = Pacer(2.0, 0.05)
    starts = run(p, 200, 0.01, 0.001, stall_at=50, stall=stall)
    (t0, w0), (t1, w1) = starts[0], starts[-1]
    assert (t1 - t0) / (w1 - w0) == pytest.approx(2.0, rel=1e-9)
    assert p.drops == 0


def test_long_stall_is_dropped_not_raced():
    p = Pacer(2.0, 0.05)
    starts = run(p, 200, 0.01, 0.001, stall_at=50, stall=0.1)  # 200 ms of sim time late
    assert p.drops == 1
    assert p.dropped == pytest.approx(0.2 - 0.01 + 0.002, abs=0.005)
    # After the stall every step takes its full wall period again: no burst.
    assert min(periods_after(starts, 50)) == pytest.approx(0.01 / 2.0, rel=1e-6)


def test_without_a_lag_budget_the_stall_is_raced():
    # The same stall with an unlimited budget: the loop runs steps back to back (the
    # behaviour this class exists to bound), which shows the test above can fail.
    p = Pacer(2.0, 10.0)
    starts = run(p, 200, 0.01, 0.001, stall_at=50, stall=0.1)
    assert p.drops == 0 and min(periods_after(starts, 50)) == pytest.approx(0.001)


def test_as_fast_as_possible_never_waits():
    assert Pacer(0.0, 0.05).wait(10.0, 0.0) == 0.0


@pytest.mark.parametrize("rtf,lag", [(-1.0, 0.05), (1.0, -0.1)])
def test_bad_parameters_are_named(rtf, lag):
    with pytest.raises(ValueError, match="real_time_factor|max_lag"):
        Pacer(rtf, lag)


class _Link:
    """A fake wall clock and PLC link: ``serve(timeout)`` advances the wall clock by the
    timeout and delivers a fresh setpoint at ``arrives`` (wall s; None: never)."""

    def __init__(self, sim_t, fresh_since, arrives=None, driving=True):
        self.wall, self.sim_t, self.fresh_since, self.arrives, self.driving = 0.0, sim_t, fresh_since, arrives, driving
        self.served = 0

    def serve(self, timeout):
        self.served += 1
        self.wall += timeout
        if self.arrives is not None and self.wall >= self.arrives:
            self.fresh_since = self.sim_t

    def wait(self, hold):
        return hold.wait(self.sim_t, lambda: self.fresh_since, lambda: self.driving, self.serve, lambda: self.wall)


def test_loop_hold_waits_for_a_late_client_then_time_runs_on():
    hold = LoopHold(lag=0.1, budget=0.5)
    assert not hold.due(10.0, 9.95, True)  # setpoints 50 ms old: step
    assert hold.due(10.0, 9.85, True)  # 150 ms old: wait
    link = _Link(10.0, 9.85, arrives=0.12)
    waited = link.wait(hold)
    assert 0.12 <= waited < 0.13 and link.fresh_since == 10.0
    assert not hold.due(10.0, link.fresh_since, True)
    assert (hold.holds, hold.given_up) == (1, 0) and hold.held == pytest.approx(waited)


def test_loop_hold_gives_up_once_on_a_frozen_client_so_the_watchdog_brakes():
    hold = LoopHold(lag=0.1, budget=0.5)
    link = _Link(10.0, 9.85, arrives=None)
    assert link.wait(hold) == pytest.approx(0.5, abs=0.006)
    assert hold.given_up == 1
    # The same stall is not waited for again: sim time runs on to the watchdog (0.2 s)
    for t in (10.01, 10.1, 10.3):
        assert not hold.due(t, 9.85, True)
    # A later stall, after the client came back, is waited for again
    assert hold.due(20.0, 19.8, True)


def test_loop_hold_never_waits_when_the_plc_does_not_drive_or_when_off():
    assert not LoopHold(0.1, 0.5).due(10.0, 0.0, False)  # SAFE, HALT: nothing to keep fresh
    assert not LoopHold(0.0, 0.5).due(10.0, 0.0, True)  # factor 1: the world does not wait
    assert not LoopHold(0.1, 0.0).due(10.0, 0.0, True)
    link = _Link(10.0, 9.0, arrives=None, driving=True)
    hold = LoopHold(0.1, 0.5)

    def serve(timeout):  # the PLC brakes on its own (a mode request) during the wait
        link.serve(timeout)
        link.driving = False
    assert hold.wait(10.0, lambda: link.fresh_since, lambda: link.driving, serve, lambda: link.wall) < 0.01
    with pytest.raises(ValueError, match="loop hold"):
        LoopHold(-1.0, 0.5)


WATCH = {"localization/odom": 0.2, "localization/predicted": 0.1}


def test_stale_slowdown_runs_at_real_time_until_every_stream_is_fresh_again():
    sd = StaleSlowdown(WATCH, budget=2.0)
    sd.seen("localization/odom", 9.9)
    sd.seen("localization/predicted", 9.98)
    assert sd.factor(5.0, 10.0, True, wall=0.0) == 5.0  # 0.1 and 0.02 s old: fresh
    sd.seen("localization/odom", 9.85)  # an older stamp arriving late changes nothing
    assert sd.factor(5.0, 10.15, True, wall=0.01) == 1.0  # odom 0.25 s old
    assert sd.slow and sd.stale(10.15) == ["localization/odom", "localization/predicted"]
    assert sd.factor(5.0, 10.2, True, wall=0.06) == 1.0
    sd.seen("localization/odom", 10.15)
    sd.seen("localization/predicted", 10.2)
    assert sd.factor(5.0, 10.21, True, wall=0.07) == 5.0 and not sd.slow
    assert sd.episodes == {"localization/odom": 1, "localization/predicted": 1}
    assert sd.slow_wall == pytest.approx(0.06) and sd.given_up == 0


def test_stale_slowdown_as_fast_as_possible_also_slows_to_real_time():
    sd = StaleSlowdown(WATCH, budget=2.0)
    sd.seen("localization/odom", 0.0)
    assert sd.factor(0.0, 1.0, True, wall=0.0) == 1.0


def test_stale_slowdown_watches_a_stream_only_from_its_first_message_and_while_driving():
    sd = StaleSlowdown(WATCH, budget=2.0)
    assert sd.factor(5.0, 100.0, True, wall=0.0) == 5.0  # no localization running
    sd.seen("localization/predicted", 10.0)
    assert sd.factor(5.0, 100.0, False, wall=0.0) == 5.0  # the PLC does not drive: nothing acts on it
    assert sd.factor(5.0, 100.0, True, wall=0.0) == 1.0


def test_stale_slowdown_never_at_or_below_real_time_or_when_off():
    for rtf in (1.0, 0.5):
        sd = StaleSlowdown(WATCH, budget=2.0)
        sd.seen("localization/odom", 0.0)
        assert sd.factor(rtf, 100.0, True, wall=0.0) == rtf
    for off in (StaleSlowdown({}, 2.0), StaleSlowdown(WATCH, 0.0), StaleSlowdown({"a": 0.0}, 2.0)):
        off.seen("a", 0.0)
        off.seen("localization/odom", 0.0)
        assert not off.enabled and off.factor(5.0, 100.0, True, wall=0.0) == 5.0


def test_stale_slowdown_gives_up_once_on_a_stream_that_stopped():
    sd = StaleSlowdown(WATCH, budget=2.0)
    sd.seen("localization/odom", 10.0)
    assert sd.factor(5.0, 10.3, True, wall=0.0) == 1.0
    assert sd.factor(5.0, 11.0, True, wall=1.9) == 1.0
    assert sd.factor(5.0, 12.1, True, wall=2.1) == 5.0  # the node died: the run goes on at its factor
    assert sd.given_up == 1 and not sd.slow and sd.slow_wall == pytest.approx(2.1)
    assert sd.factor(5.0, 50.0, True, wall=3.0) == 5.0  # the same silence is not waited for again
    sd.seen("localization/odom", 60.0)  # back (a restart): watched again
    assert sd.factor(5.0, 60.5, True, wall=4.0) == 1.0


def test_stale_slowdown_first_slows_to_a_fraction_of_the_factor_then_to_real_time():
    sd = StaleSlowdown(WATCH, budget=2.0, fraction=0.7, escalate=0.1)
    sd.seen("localization/predicted", 10.0)
    assert sd.factor(5.0, 10.2, True, wall=0.0) == pytest.approx(3.5)  # a short wait for a core
    assert sd.factor(5.0, 10.29, True, wall=0.5) == pytest.approx(3.5)  # the escalation is in sim time
    assert sd.escalated == 0
    assert sd.factor(5.0, 10.31, True, wall=0.51) == 1.0  # still stale 0.1 sim s after it began
    assert sd.factor(5.0, 10.32, True, wall=0.52) == 1.0 and sd.escalated == 1
    sd.seen("localization/predicted", 10.32)
    assert sd.factor(5.0, 10.33, True, wall=0.53) == 5.0 and not sd.slow
    assert sd.factor(5.0, 10.5, True, wall=0.6) == pytest.approx(3.5)  # a new episode starts at the fraction
    assert sd.episodes["localization/predicted"] == 2 and sd.escalated == 1
    # never below real time, and as fast as possible has no fraction: real time
    assert sd.factor(1.2, 10.5, True, wall=0.61) == 1.0
    assert sd.factor(0.0, 10.5, True, wall=0.62) == 1.0
    # fraction 0 (the default): every episode at real time at once, each counted as such
    sd = StaleSlowdown(WATCH, budget=2.0, fraction=0.0, escalate=0.1)
    sd.seen("localization/predicted", 10.0)
    assert sd.factor(5.0, 10.2, True, wall=0.0) == 1.0 and sd.escalated == 1


def test_stale_slowdown_bad_parameters_are_named():
    with pytest.raises(ValueError, match="stale slowdown"):
        StaleSlowdown({"localization/odom": -0.1}, 2.0)
    with pytest.raises(ValueError, match="stale slowdown"):
        StaleSlowdown(WATCH, float("nan"))
    for fraction, escalate in ((1.0, 0.1), (-0.1, 0.1), (float("nan"), 0.1), (0.5, -1.0), (0.5, float("nan"))):
        with pytest.raises(ValueError, match="fraction"):
            StaleSlowdown(WATCH, 2.0, fraction, escalate)


def test_a_new_factor_keeps_the_next_step_on_its_time_and_paces_the_ones_after():
    p = Pacer(8.0, max_lag=0.05)
    p.anchor(10.0, 100.0)
    # a step of 10 ms ran; at factor 8 the next is due 1.25 ms after the anchor, and
    # slowing down it keeps that time
    p.set_factor(1.0, 10.01, 100.0005)
    assert p.wait(10.01, 100.0005) == pytest.approx(0.00075)  # not at once
    assert p.wait(10.02, 100.00125) == pytest.approx(0.01)  # then 10 ms a step
    # changed every step: still 1 / factor a step
    wall, t = 100.00125, 10.02
    for k in range(100):
        f = 2.0 + 0.001 * k
        p.set_factor(f, t, wall)
        wall += p.wait(t, wall)
        t += 0.01
    assert (t - 10.02) / (wall - 100.00125) == pytest.approx(2.05, rel=0.03)
    # late (behind the old schedule): the next step now, no burst to catch up
    p.set_factor(3.0, t, wall + 1.0)
    assert p.wait(t, wall + 1.0) == 0.0 and p.wait(t + 0.01, wall + 1.0) == pytest.approx(0.01 / 3)
    # speeding up: the next step when the new factor puts it, not the old one's 10 ms
    p = Pacer(1.0, max_lag=0.05)
    p.anchor(10.0, 100.0)
    p.set_factor(5.0, 10.01, 100.001)
    assert p.wait(10.01, 100.001) == pytest.approx(0.001)  # due at 100.002, not 100.01
    with pytest.raises(ValueError):
        p.set_factor(-1.0, t, wall)
