"""Pacer: waits when ahead, makes up a short lag, drops a long one."""
import pytest

from quadrivio_sim.pacing import Pacer


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
