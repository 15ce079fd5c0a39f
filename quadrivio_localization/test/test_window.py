"""FixedLagWindow: exact on a linear chain, cheap per update, and safe to marginalise."""

import gtsam
import numpy as np
import pytest

from quadrivio_localization.window import FixedLagWindow

X = gtsam.symbol_shorthand.X
C = gtsam.symbol_shorthand.C  # a slowly varying per-keyframe vector, like the calibration states
DT = 0.05


def _stream(n, seed=0, late=20, skip=True):
    """A linear-Gaussian chain: 2-D positions X_k and 2-D offsets C_k, odometry between X's
    (and, with ``skip``, a factor across three keyframes, like the smoother's constant-velocity
    factor), a random walk between C's, and position fixes z = X + C that arrive ``late``
    keyframes after their keyframe. Yields (graph, values, stamps) per keyframe, and all
    factors for the batch solution."""
    rng = np.random.default_rng(seed)
    odo = gtsam.noiseModel.Isotropic.Sigma(2, 0.05)
    walk = gtsam.noiseModel.Isotropic.Sigma(2, 0.01)
    fix = gtsam.noiseModel.Isotropic.Sigma(2, 0.5)
    acc = gtsam.noiseModel.Isotropic.Sigma(2, 0.2)
    truth = np.cumsum(rng.normal(0.1, 0.02, (n, 2)), axis=0)
    everything = gtsam.NonlinearFactorGraph()
    fixes = {}
    for k in range(n):
        graph, values, stamps = gtsam.NonlinearFactorGraph(), gtsam.Values(), {}
        if k == 0:
            graph.add(gtsam.PriorFactorVector(X(0), truth[0], gtsam.noiseModel.Isotropic.Sigma(2, 1.0)))
            graph.add(gtsam.PriorFactorVector(C(0), np.zeros(2), gtsam.noiseModel.Isotropic.Sigma(2, 0.3)))
        else:
            graph.add(gtsam.BetweenFactorVector(X(k - 1), X(k), truth[k] - truth[k - 1] + rng.normal(0, 0.05, 2), odo))
            graph.add(gtsam.BetweenFactorVector(C(k - 1), C(k), np.zeros(2), walk))
            if skip and k >= 2 and k % 7 == 0:
                graph.add(gtsam.BetweenFactorVector(X(k - 2), X(k), truth[k] - truth[k - 2], acc))
        fixes[k] = truth[k] + rng.normal(0, 0.5, 2)
        if k - late >= 0:
            j = k - late
            graph.add(gtsam.CustomFactor(fix, [X(j), C(j)], _fix_error(fixes[j])))
        values.insert(X(k), truth[k] + rng.normal(0, 0.3, 2))
        values.insert(C(k), np.zeros(2))
        stamps[X(k)] = stamps[C(k)] = k * DT
        everything.push_back(graph)
        yield graph, values, stamps, everything


def _fix_error(z):
    def error(this, values, H):
        x, c = values.atVector(this.keys()[0]), values.atVector(this.keys()[1])
        if H is not None:
            H[0], H[1] = np.eye(2), np.eye(2)
        return x + c - z
    return error


def _batch(graph, n):
    initial = gtsam.Values()
    for k in range(n):
        initial.insert(X(k), np.zeros(2))
        initial.insert(C(k), np.zeros(2))
    return gtsam.GaussNewtonOptimizer(graph, initial).optimize()


@pytest.mark.parametrize("lag,chunk", [(1.0, 0.5), (3.0, 1.0), (2.0, 0.05)])
def test_a_linear_chain_matches_the_batch_solution(lag, chunk):
    """Linear factors: marginalisation is exact, so the newest estimate is the full batch
    solution's, whatever the lag, the chunks and the late factors."""
    w = FixedLagWindow(lag, gtsam.ISAM2Params(), chunk=chunk)
    n = 240
    for k, (graph, values, stamps, everything) in enumerate(_stream(n)):
        w.update(graph, values, stamps)
        if k in (30, 120, n - 1):
            batch = _batch(everything, k + 1)
            est = w.calculateEstimate()
            np.testing.assert_allclose(est.atVector(X(k)), batch.atVector(X(k)), atol=1e-6)
            np.testing.assert_allclose(est.atVector(C(k)), batch.atVector(C(k)), atol=1e-6)
    # the window spans lag to lag + chunk s
    stamps = sorted(set(w.timestamps().values()))
    assert lag - 1e-9 <= stamps[-1] - stamps[0] < lag + chunk + 1e-9
    assert w.marginalized == 2 * n - len(w.timestamps())
    if chunk >= 10 * DT:  # chunks of many keyframes: the updates keep the order marginalisation needs
        assert w.repairs == 0


def test_an_update_re_eliminates_only_the_top_of_the_chain():
    """The newest keyframe stays at the root: appending one re-eliminates a few keyframes'
    variables, and a fix 20 keyframes late about 20 keyframes' worth, not the window (GTSAM's
    IncrementalFixedLagSmoother re-eliminated all of it, every time)."""
    w = FixedLagWindow(3.0, gtsam.ISAM2Params(), chunk=1.0)
    appended, late = [], []
    for k, (graph, values, stamps, _) in enumerate(_stream(400, late=20, skip=False)):
        w.update(graph, values, stamps)
        if k > 100:
            late.append(w.last_result.getVariablesReeliminated())
    window = len(w.timestamps())
    assert window >= 2 * 60
    # 21 keyframes of 2 variables, and a few more where a clique straddles the fix's keyframe
    assert max(late) <= 2 * (21 + 5) < 0.4 * window, f"a fix 20 keyframes late re-eliminated {max(late)} of {window}"
    w2 = FixedLagWindow(3.0, gtsam.ISAM2Params(), chunk=1.0)
    for k, (graph, values, stamps, _) in enumerate(_stream(200, late=10 ** 6, skip=False)):
        w2.update(graph, values, stamps)
        if k > 100:
            appended.append(w2.last_result.getVariablesReeliminated())
    # the two keyframes of the new factors, their cliques' neighbours; a relinearised key a
    # few keyframes back now and then
    assert np.median(appended) <= 8 and max(appended) <= 20, f"appending re-eliminated up to {max(appended)}"


def test_nonlinear_poses_with_skipping_factors_survive_marginalisation():
    """Pose2 keyframes with odometry, factors across three keyframes and late priors: the
    pattern that once made marginalizeLeaves crash the process (a key leaving the window that
    was not first in its clique). The estimate follows the truth."""
    w = FixedLagWindow(1.0, gtsam.ISAM2Params(), chunk=0.25)
    rng = np.random.default_rng(3)
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.02, 0.02, 0.01]))
    fix = gtsam.noiseModel.Isotropic.Sigma(3, 0.3)
    step = gtsam.Pose2(0.1, 0.0, 0.02)
    truth = [gtsam.Pose2()]
    for k in range(600):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        if k == 0:
            graph.add(gtsam.PriorFactorPose2(X(0), truth[0], fix))
        else:
            truth.append(truth[-1].compose(step))
            graph.add(gtsam.BetweenFactorPose2(X(k - 1), X(k), step, odo))
            if k >= 2:
                graph.add(gtsam.BetweenFactorPose2(X(k - 2), X(k), step.compose(step), odo))
            if k >= 8 and rng.random() < 0.3:
                graph.add(gtsam.PriorFactorPose2(X(k - 8), truth[k - 8], fix))
        values.insert(X(k), truth[k].compose(gtsam.Pose2(*rng.normal(0, [0.05, 0.05, 0.01]))))
        w.update(graph, values, {X(k): k * DT})
        if k % 50 == 49:  # the solution read key by key is the whole estimate's, to the bit
            whole, solution = w.calculateEstimate(), w.solution()
            assert sorted(whole.keys()) == sorted(w.timestamps())
            for key in whole.keys():
                assert solution.exists(key)
                a, b = whole.atPose2(key), solution.atPose2(key)
                assert (a.x(), a.y(), a.theta()) == (b.x(), b.y(), b.theta())
            assert not solution.exists(X(0)) and not solution.exists(X(k + 1))
    est = w.calculateEstimate().atPose2(X(599))
    assert np.hypot(est.x() - truth[-1].x(), est.y() - truth[-1].y()) < 1.0
    assert len(w.timestamps()) <= (1.0 + 0.25) / DT + 1


def test_the_solution_key_by_key_is_the_whole_estimate():
    """Vectors too, with late factors re-solving older keys (what the smoother reads)."""
    w = FixedLagWindow(1.0, gtsam.ISAM2Params(), chunk=0.5)
    for k, (graph, values, stamps, _) in enumerate(_stream(120, seed=4, late=10)):
        w.update(graph, values, stamps)
        whole, solution = w.calculateEstimate(), w.solution()
        for key in whole.keys():
            assert np.array_equal(whole.atVector(key), solution.atVector(key))
        assert len(whole.keys()) == len(w.timestamps())


def test_levels_respect_the_budget_and_time_order():
    w = FixedLagWindow(3.0, gtsam.ISAM2Params(), chunk=1.0)
    for k in range(81):
        w.stamps[k] = k * DT
    for reach in (80, 70, 45, 20, 0):
        for budget in (1, 2, 3, 5, 11, 40, 200):
            lv = w.levels(budget, reach * DT)
            seq = [lv[t] for t in sorted(lv)]
            in_range = 4 - reach // 20 + 1  # chunks from the reach's to the newest
            # CCOLAMD: no group above the number of variables it orders, of which there are
            # at least the new factors' keys (the budget) and a key per chunk in range
            assert max(seq) <= max(budget, in_range) - 1
            assert seq[0] == 0 and all(0 <= b - a <= 1 for a, b in zip(seq, seq[1:]))  # time order, no gap
            # the chunks the update re-eliminates are ordered chunk by chunk
            firsts = [lv[c * 20 * DT] for c in range(reach // 20, 5)]
            lasts = [lv[min(80, c * 20 + 19) * DT] for c in range(reach // 20, 5)]
            assert all(lasts[i] < firsts[i + 1] for i in range(len(firsts) - 1))
            if budget >= in_range + 3:  # room left: the newest stamps get a level each
                assert lv[79 * DT] < lv[80 * DT]
    assert sorted(set(w.levels(1000, 0.0).values())) == list(range(81))


def test_a_bad_chunk_is_refused():
    with pytest.raises(ValueError, match="chunk"):
        FixedLagWindow(3.0, gtsam.ISAM2Params(), chunk=0.0)
