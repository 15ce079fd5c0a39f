"""The GPS gate alone, on synthetic innovations: receivers of 3 cm and of 3 m judged by
their own covariances, bursts that end, outages that end bursts, reasons counted."""
import math

import numpy as np
import pytest

from quadrivio_localization.gps_gate import MULTIPATH, OUTLIER, GpsGate, GpsGateParams, eigen_range


def settled_gate(**over):
    g = GpsGate(GpsGateParams(**over))
    g.used = g.p.settle_fixes
    return g


def clean_fixes(g, P, R, Q, n=10, period=0.2):
    """Feed ``n`` fixes on the estimate with steps as estimated; the next fix's time."""
    t = 0.0
    for _ in range(n):
        assert g.decide(t, np.zeros(2), P, R, (), (np.zeros(2), R, R, Q)).use
        t += period
    return t


def feed(gate, sigma, offsets, rate=5.0, P=0.05, seed=0, group_n=None):
    """Feed fixes of white noise ``sigma`` (what the receiver reports) plus ``offsets[i]``
    (multipath: unseen by the receiver) against a perfect estimate of std ``P`` [m];
    each with the look-ahead group of the fixes that follow it."""
    rng = np.random.default_rng(seed)
    R = np.eye(2) * sigma ** 2
    Pm = np.eye(2) * P ** 2
    n = len(offsets)
    nus = [rng.normal(0, sigma, 2) + np.asarray(offsets[i], float) for i in range(n)]
    k = int(round(gate.p.group * rate)) if group_n is None else group_n
    verdicts = []
    prev = None
    for i in range(n):
        group = [(nus[j], R) for j in range(i + 1, min(n, i + 1 + k))]
        behind = [(nus[j], R) for j in range(max(0, i - k), i)]
        step = None if prev is None else (nus[i] - prev, R, R, np.eye(2) * 1e-4)
        prev = nus[i]
        verdicts.append(gate.decide(i / rate, nus[i], Pm, R, group, step, behind))
    return verdicts


@pytest.mark.parametrize("sigma", [0.03, 0.3, 3.0])
def test_clean_fixes_are_used_whatever_the_receiver(sigma):
    g = settled_gate()
    v = feed(g, sigma, [(0.0, 0.0)] * 500, P=sigma)
    assert sum(not x.use for x in v) <= 2, g.summary()  # chi-square tails at p ~ 1e-4


@pytest.mark.parametrize("sigma,offset", [(0.03, 1.2), (1.5, 7.0), (3.0, 12.0)])
def test_a_burst_is_rejected_and_ends(sigma, offset):
    """A burst of a few sigmas per fix (7 m under 1.5 m of white noise) is a many-sigma
    mean over its group; the fixes after it are used again at once."""
    g = settled_gate()
    offsets = [(0.0, 0.0)] * 50 + [(offset, 0.0)] * 25 + [(0.0, 0.0)] * 50
    v = feed(g, sigma, offsets, P=0.5 * sigma)
    during = v[52:75]  # the first fix or two of a burst may pass: the Huber kernel takes them
    after = v[77:]
    assert np.mean([not x.use for x in during]) >= 0.9, g.summary()
    assert all(x.reason == MULTIPATH or x.reason == OUTLIER for x in during if not x.use)
    assert np.mean([x.use for x in after]) >= 0.97, g.summary()
    assert g.counts[MULTIPATH] + g.counts[OUTLIER] >= 20


def test_an_outage_ends_a_jump_burst():
    """The old fixed-threshold jump test held a burst open across a 14 s outage and dropped
    every fix after it: a gap longer than jump_window ends a burst."""
    g = settled_gate(group=0.0)
    R = np.eye(2) * 0.03 ** 2
    P = np.eye(2) * 0.05 ** 2
    t = clean_fixes(g, P, R, np.eye(2) * 1e-4)
    jump = np.array([1.5, 0.0])
    assert not g.decide(t, jump, P, R, (), (jump, R, R, np.eye(2) * 1e-4)).use  # the burst starts
    t += 14.0  # outage, then the fixes are good again: the estimate (dead-reckoned) knows it is less sure
    v = g.decide(t, np.array([0.1, 0.0]), P * 4, R, (), (np.array([-1.4, 0.0]), R, R, np.eye(2) * 0.01))
    assert v.use and g.burst is None


def test_an_uncertain_estimate_accepts_what_a_sure_one_rejects():
    """Scaled by the estimate's covariance: after an outage the dead-reckoned estimate is
    uncertain, and a fix 2 m off is news, not an outlier."""
    R = np.eye(2) * 0.03 ** 2
    nu = np.array([2.0, 0.0])
    assert not settled_gate().decide(0.0, nu, np.eye(2) * 0.1 ** 2, R).use
    assert settled_gate().decide(0.0, nu, np.eye(2) * 1.0 ** 2, R).use


def test_a_lost_estimate_yields():
    """Every fix rejected for yield_after s: the estimate, not the receiver, is wrong."""
    g = settled_gate(yield_after=5.0)
    R, P = np.eye(2) * 0.01, np.eye(2) * 0.01
    verdicts = [g.decide(0.2 * i, np.array([5.0, 0.0]), P, R) for i in range(40)]
    assert not verdicts[0].use and any(v.yielded for v in verdicts) and g.yielded >= 1
    assert "accepted after 5 s" in g.summary()


def test_unsettled_gate_uses_everything_and_skips_are_counted():
    g = GpsGate(GpsGateParams(settle_fixes=3))
    for i in range(3):
        assert g.decide(i, np.array([100.0, 0.0]), np.eye(2), np.eye(2)).use
    assert not g.decide(3, np.array([100.0, 0.0]), np.eye(2), np.eye(2)).use
    g.skip("no fix")
    g.skip("too old")
    assert g.counts["no fix"] == 1 and g.counts["too old"] == 1 and g.counts[OUTLIER] == 1
    assert g.summary() == "1 no fix, 1 too old, 1 outlier"


def test_status_floors_a_fix_that_claims_too_much():
    p = GpsGateParams()
    assert p.status_floor(0) == pytest.approx(0.25)  # a plain FIX is not believed below 0.5 m
    assert p.status_floor(2) == pytest.approx(1e-4)
    assert p.status_floor(7) == p.status_floor(2) and p.status_floor(-3) == p.status_floor(0)
    assert math.isfinite(GpsGate(p).last_d2) is False


def test_a_jump_of_the_estimates_own_making_ends_when_the_estimate_can_no_longer_tell():
    """A wheel that slid: the estimate fell 0.3 m behind in one step and dead-reckons on from
    there, its uncertainty growing; the fixes, right all along, never 'jump back'. They were
    held out for yield_after (30 s); they are taken again once the estimate is unsure enough
    that a fix 0.3 m away is no news to it."""
    g = settled_gate(group=0.0)
    R = np.eye(2) * 0.03 ** 2
    Q = np.eye(2) * 1e-4
    t = clean_fixes(g, np.eye(2) * 0.02 ** 2, R, Q)
    slid = np.array([0.3, 0.0])
    verdicts = []
    for i in range(100):  # 20 s at 5 Hz, the estimate's std growing 2 cm a second
        P = np.eye(2) * (0.02 + 0.02 * 0.2 * i) ** 2
        verdicts.append(g.decide(t, slid, P, R, (), (slid if i == 0 else np.zeros(2), R, R, Q)))
        t += 0.2
    assert not verdicts[0].use and verdicts[0].reason == MULTIPATH  # it did look like a burst
    back = next(i for i, v in enumerate(verdicts) if v.use)
    assert 3.0 <= 0.2 * back <= 8.0, back  # std 0.08-0.18 m: 0.3 m within jump_gate / 4
    assert all(v.use for v in verdicts[back:]) and g.yielded == 0


def test_a_sure_estimate_keeps_a_jump_burst_out():
    """The same step of 1.2 m against an estimate that stays sure (std 3 cm): multipath, held
    out until it jumps back."""
    g = settled_gate(group=0.0)
    R, P, Q = np.eye(2) * 0.03 ** 2, np.eye(2) * 0.03 ** 2, np.eye(2) * 1e-4
    t = clean_fixes(g, P, R, Q)
    off = np.array([1.2, 0.0])
    during = [g.decide(t + 0.2 * i, off, P, R, (), (off if i == 0 else np.zeros(2), R, R, Q)) for i in range(50)]
    assert not any(v.use for v in during)
    after = g.decide(t + 10.0, np.zeros(2), P, R, (), (-off, R, R, Q))
    assert after.use and g.burst is None


@pytest.mark.parametrize("burst_before_fault", [True, False])
def test_a_fault_found_later_does_not_let_an_earlier_burst_in(burst_before_fault):
    """A wheel slip found at t unsettles the gate (the estimate rode false odometry since
    about t - window): the next fixes go in untested. A burst that began before that, while
    the estimate was trusted, is no error of the estimate's: its fixes stay out until they
    jump back (found on rough terrain: a slip 4 s into a 5.4 m burst let it in, the estimate
    jumped 5 m). A "burst" that began after it may be the estimate's own error: cleared."""
    g = settled_gate(group=0.0)
    R, P, Q = np.eye(2) * 0.3 ** 2, np.eye(2) * 0.1 ** 2, np.eye(2) * 1e-3
    t = clean_fixes(g, P, R, Q)
    off = np.array([5.4, 0.0])
    assert not g.decide(t, off, P, R, (), (off, R, R, Q)).use  # the burst starts at t
    fault_from = t + 1.0 if burst_before_fault else t - 1.0
    g.unsettle(keep_burst_before=fault_from)
    during = [g.decide(t + 0.2 * i, off, P, R, (), (np.zeros(2), R, R, Q)) for i in range(1, 11)]
    if burst_before_fault:
        assert not any(v.use for v in during) and g.burst is not None
        after = g.decide(t + 2.2, np.zeros(2), P, R, (), (-off, R, R, Q))  # it jumps back
        assert after.use and g.burst is None
    else:
        assert all(v.use for v in during)


def test_a_burst_that_begins_while_unsettled_by_a_fault_is_still_a_jump():
    """Unsettled by a fault found later (a wheel slip), the gate takes the next fixes untested:
    the estimate's position is in doubt. Its motion over one fix period is not: a 5.5 m step of
    the fixes 1.4 s into the slip is a burst (on rough ground at 3 m/s it went in untested, the
    estimate jumped 4 m and the follower aborted). At start-up, before the estimate has ever
    settled, no step is judged."""
    g = settled_gate(group=0.0)
    R, P, Q = np.eye(2) * 0.3 ** 2, np.eye(2) * 0.1 ** 2, np.eye(2) * 0.3 ** 2  # Q: no odometry over the step
    t = clean_fixes(g, P, R, Q)
    g.unsettle(keep_burst_before=t - 1.0)
    wrong = np.array([1.0, 0.5])  # the estimate rode the spinning wheels: 1.1 m off, the fixes right
    settling = [g.decide(t + 0.2 * i, wrong, P, R, (), (np.zeros(2), R, R, Q)) for i in range(7)]
    assert all(v.use for v in settling)  # untested: they pull the estimate back
    off = wrong + np.array([5.5, 0.0])
    t += 1.4
    burst = [g.decide(t + 0.2 * i, off, P, R, (), (off - wrong if i == 0 else np.zeros(2), R, R, Q))
             for i in range(10)]
    assert not any(v.use for v in burst) and all(v.reason == MULTIPATH for v in burst)
    back = g.decide(t + 2.0, wrong, P, R, (), (wrong - off, R, R, Q))
    assert back.use and g.burst is None
    fresh = GpsGate(GpsGateParams(group=0.0))  # never settled: every fix in, steps or not
    assert fresh.decide(0.0, np.zeros(2), P, R).use
    assert fresh.decide(0.2, off, P, R, (), (off, R, R, Q)).use and fresh.burst is None


def test_a_burst_cleared_by_a_fault_leaves_no_step_judged_until_settled():
    """A burst that began after the fault's earliest start may be the estimate's error: the
    fault clears it and its fixes go in. Their jump back 0.4 s later is then no burst's
    start: judged as one, it held the right fixes out and the estimate ran 10 m off (rough
    ground at 3 m/s, seed 9)."""
    g = settled_gate(group=0.0)
    R, P, Q = np.eye(2) * 0.3 ** 2, np.eye(2) * 0.1 ** 2, np.eye(2) * 1e-3
    t = clean_fixes(g, P, R, Q)
    off = np.array([4.6, 0.0])
    assert not g.decide(t, off, P, R, (), (off, R, R, Q)).use
    g.unsettle(keep_burst_before=t - 0.2)  # the burst began after the fault's earliest start
    assert g.burst is None
    assert g.decide(t + 0.2, off, P, R, (), (np.zeros(2), R, R, Q)).use  # untested
    back = [g.decide(t + 0.4 + 0.2 * i, off * 0.5, P, R, (), (-off if i == 0 else np.zeros(2), R, R, Q))
            for i in range(5)]
    assert all(v.use for v in back) and g.burst is None


def test_the_closed_form_eigenvalues_are_lapacks():
    rng = np.random.default_rng(7)
    for scale in (1e-4, 1.0, 1e3):
        for _ in range(200):
            a = rng.normal(size=(2, 2)) * scale
            S = a @ a.T + np.diag(rng.uniform(0, scale, 2))
            lo, hi = eigen_range(S)
            ref = np.linalg.eigvalsh(S)
            assert lo == pytest.approx(ref[0], rel=1e-9, abs=1e-12 * scale ** 2)
            assert hi == pytest.approx(ref[1], rel=1e-9)
    assert eigen_range(np.diag([2.0, 3.0])) == (2.0, 3.0)  # diagonal: exact
    assert eigen_range(np.eye(2) * 0.5) == (0.5, 0.5)
