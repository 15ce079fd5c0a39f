"""The GNSS oracle (quadrivio.gnss_bound): the floor of a causal estimator's error."""

import math

import numpy as np
import pytest

from quadrivio.gnss_bound import oracle_errors


def _receiver(seed, n=80, sigma=1.0, tau=20.0, white=1.5, rate=2.0):
    """Fix-minus-truth offsets of a drifting receiver, with irregular epochs."""
    g = np.random.default_rng(seed)
    t = np.cumsum(g.uniform(0.5, 1.5, n) / rate)
    d = np.zeros((n, 2))
    d[0] = g.normal(0.0, sigma, 2)
    for i in range(1, n):
        phi = math.exp(-(t[i] - t[i - 1]) / tau)
        d[i] = phi * d[i - 1] + sigma * math.sqrt(1 - phi * phi) * g.normal(0.0, 1.0, 2)
    var = (white * g.uniform(1.0, 2.0, n)) ** 2  # degraded spells: each fix its own variance
    y = d + g.normal(0.0, 1.0, (n, 2)) * np.sqrt(var)[:, None]
    return t, y, var, d


def gls_errors(t, offsets, white_var, sigma, tau):
    """:func:`oracle_errors` by brute force (every fix used; O(n^4)): at each epoch the
    generalised least-squares mean of the offsets so far under the drift's covariance."""
    t = np.asarray(t, float)
    y = np.asarray(offsets, float)
    y = y[:, None] if y.ndim == 1 else y
    C = sigma * sigma * np.exp(-np.abs(t[:, None] - t[None, :]) / tau) + np.diag(np.asarray(white_var, float))
    out = np.zeros(y.shape)
    for k in range(len(t)):
        w = np.linalg.solve(C[:k + 1, :k + 1], np.ones(k + 1))
        out[k] = (w / w.sum()) @ y[:k + 1]
    return out


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_filter_is_the_generalised_least_squares_it_stands_for(seed):
    t, y, var, _ = _receiver(seed)
    fast, slow = oracle_errors(t, y, var, 1.0, 20.0), gls_errors(t, y, var, 1.0, 20.0)
    assert np.allclose(fast, slow, atol=1e-6), np.abs(fast - slow).max()


def test_without_drift_it_is_the_weighted_running_mean():
    t, y, var, _ = _receiver(3, sigma=0.0)
    w = 1.0 / var
    expected = np.cumsum(y * w[:, None], axis=0) / np.cumsum(w)[:, None]
    assert np.allclose(oracle_errors(t, y, var, 0.0, 60.0), expected, atol=1e-9)


def test_it_beats_following_the_fixes_over_many_seeds_but_not_the_drift_floor_at_once():
    """Over seeds, the oracle's error is below the drift's (what a fix follower scores),
    and more so the longer the run is against the drift's correlation time."""
    short, long_ = [], []
    for seed in range(40):
        t, y, var, d = _receiver(seed, n=400, tau=20.0)
        e = oracle_errors(t, y, var, 1.0, 20.0)
        drift = np.sqrt(np.mean(np.sum(d ** 2, axis=1)))
        short.append(np.sqrt(np.mean(np.sum(e[:40] ** 2, axis=1))) / drift)
        long_.append(np.sqrt(np.mean(np.sum(e[-100:] ** 2, axis=1))) / drift)
    assert np.mean(long_) < 0.6 < np.mean(short)


def test_an_epoch_without_a_fix_keeps_the_estimate_and_a_known_multipath_fix_is_left_out():
    t = np.arange(6.0)
    y = np.array([[1.0, 0.0], [3.0, 0.0], [np.nan, np.nan], [50.0, 50.0], [2.0, 0.0], [np.nan, np.nan]])
    var = np.ones(6)
    use = [True, True, True, False, True, True]
    e = oracle_errors(t, y, var, 0.0, 10.0, use)
    assert e[0, 0] == pytest.approx(1.0) and e[1, 0] == pytest.approx(2.0)
    assert e[2, 0] == pytest.approx(2.0) and e[3, 0] == pytest.approx(2.0)  # no fix; the burst not believed
    assert e[4, 0] == pytest.approx(2.0) and e[5, 0] == pytest.approx(2.0)
    assert np.all(e[:, 1] == pytest.approx(0.0))


def test_before_the_first_fix_there_is_no_estimate():
    e = oracle_errors([0.0, 1.0, 2.0], np.array([[np.nan], [np.nan], [0.5]]), [1.0, 1.0, 1.0], 1.0, 60.0)
    assert np.isnan(e[0, 0]) and np.isnan(e[1, 0]) and e[2, 0] == pytest.approx(0.5)  # where the first fix says


@pytest.mark.parametrize("args, message", [
    (([0.0, 1.0], np.zeros((3, 2)), [1.0, 1.0], 1.0, 60.0), "2 epochs, 3 offsets"),
    (([1.0, 0.0], np.zeros((2, 2)), [1.0, 1.0], 1.0, 60.0), "back in time"),
    (([0.0, 1.0], np.zeros((2, 2)), [1.0, 1.0], math.nan, 60.0), "drift sigma nan"),
    (([0.0, 1.0], np.zeros((2, 2)), [1.0, 1.0], 1.0, 0.0), "tau 0.0"),
])
def test_bad_input_is_named(args, message):
    with pytest.raises(ValueError, match=message):
        oracle_errors(*args)
