"""The best any estimator can do with a receiver's fixes: the GNSS oracle (issue 9).

A receiver's fix is ``z = p + d + w``: the antenna ``p``, the receiver's slow drift ``d``
(first-order Gauss-Markov, ``sigma`` and ``tau`` per axis) and white noise ``w`` (its
variance per fix). Give an estimator *perfect* odometry: it knows every motion
``p_i - p_k`` exactly, so all it has to find from the fixes is one offset per axis, ``c``
in ``y_i = z_i - p_i = c + d_i + w_i`` with ``c = 0`` the truth and a flat prior on it
(where the run started is not known). Give it the receiver's *true* drift model too. Its
best estimate of ``c`` from the fixes up to now (causal, as a running smoother's newest
pose is) is the generalised least-squares mean of the ``y_i`` under the drift's
covariance, and its position error is that estimate itself.

That is a Kalman filter over ``[c, d]`` per axis, which :func:`oracle_errors` runs. Its
error is the floor of a causal estimator's position error in expectation over the
drift's and the noise's draws: no odometry is better than perfect, no drift model better
than the true one. (On one run an estimator with other weights can land below it by
chance; over seeds it cannot.) The receiver's drift alone, which the offline runs also
report, is what an estimator that follows the fixes (robot_localization's EKF) scores.

Pure and ROS-free: used by :func:`quadrivio.offline.score` with the scenario's own
receiver model, and tested against the batch generalised least squares it stands for
(``test/test_gnss_bound.py``).
"""

from __future__ import annotations

import math
from typing import Optional, Sequence

import numpy as np

FLAT = 1e8  # [m^2] prior variance of the offset: nothing known of where the run started


def oracle_errors(t: Sequence[float], offsets: np.ndarray, white_var: Sequence[float], sigma: float, tau: float,
                  use: Optional[Sequence[bool]] = None) -> np.ndarray:
    """The oracle's position error at every epoch ``t`` (seconds, increasing), per axis.

    ``offsets``: (n, axes) fix minus truth (NaN where there was no fix); ``white_var``:
    each fix's white-noise variance [m^2] (the same for every axis); ``sigma`` [m] and
    ``tau`` [s]: the receiver's drift per axis (``sigma`` 0: none). ``use``: which fixes
    the oracle believes (default: every finite one; pass False for a fix it knows is
    multipath). At an epoch without a usable fix the error is the last one (perfect
    odometry carries the estimate); before the first usable fix it is NaN.
    """
    t = np.asarray(t, float)
    y = np.asarray(offsets, float)
    if y.ndim == 1:
        y = y[:, None]
    r = np.asarray(white_var, float)
    if len(t) != len(y) or len(t) != len(r):
        raise ValueError(f"oracle_errors: {len(t)} epochs, {len(y)} offsets and {len(r)} variances")
    if len(t) > 1 and np.any(np.diff(t) < 0):
        raise ValueError("oracle_errors: epochs must not go back in time")
    if not (sigma >= 0.0 and math.isfinite(sigma)) or not (tau > 0.0 and math.isfinite(tau)):
        raise ValueError(f"oracle_errors: drift sigma {sigma} m, tau {tau} s (need sigma >= 0, tau > 0)")
    ok = np.all(np.isfinite(y), axis=1) & np.isfinite(r) & (r >= 0.0)
    if use is not None:
        ok &= np.asarray(use, bool)
    out = np.full(y.shape, math.nan)
    # One filter serves every axis: the same model, so the same gains; only the means differ.
    x = np.zeros((2, y.shape[1]))  # [c, d] per axis
    P = np.diag([FLAT, sigma * sigma])
    H = np.array([1.0, 1.0])  # a fix sees the offset plus the drift
    last, started = None, False
    for i in range(len(t)):
        if last is not None and sigma > 0.0:
            phi = math.exp(-(t[i] - last) / tau)
            F = np.array([[1.0, 0.0], [0.0, phi]])
            x = F @ x
            P = F @ P @ F.T + np.diag([0.0, sigma * sigma * (1.0 - phi * phi)])
        last = t[i]
        if ok[i]:
            S = H @ P @ H + r[i]
            if S <= 0.0:  # a perfect fix and no drift: the offset is known exactly
                S = 1e-300
            K = P @ H / S
            x = x + np.outer(K, y[i] - H @ x)
            P = P - np.outer(K, H @ P)
            P = 0.5 * (P + P.T)
            started = True
        if started:
            out[i] = x[0]
    return out
