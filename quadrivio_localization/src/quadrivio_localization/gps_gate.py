"""Which GPS fixes the smoother may believe: a test of each fix, and of the fixes around it,
against the estimate, scaled by what the receiver reports and by what the estimate knows.

A receiver's reported covariance covers its noise, never the multipath it cannot see:
multipath moves the fix by metres for seconds while the receiver still claims its usual
precision. Nothing here is a distance in metres. Every test is a squared Mahalanobis
distance of the innovation ``nu = z - h(x)`` (the fix against the estimated antenna
position plus the estimated receiver drift) under its covariance: the estimate's own
(``P``, what the smoother says it knows) plus the fix's (``R``, what the receiver says,
floored by what its status can deliver). So one receiver's 3 m scatter and another's 3 cm
are judged alike, and an estimate that has dead-reckoned through an outage, and knows it,
accepts the fixes that come back.

Two tests, each by its own reason:

* **outlier** -- one fix alone: ``nu' (P + R)^-1 nu > gate`` (chi-square, 2 degrees of
  freedom).
* **multipath** -- a fix and the fixes of the next ``group`` seconds, together: their mean
  innovation against ``P + mean(R) / n``. A burst shows as a sustained offset that single
  fixes of a noisy receiver hide (a 7 m offset under 1.5 m of white noise is a 2-sigma
  fix, but 4 such fixes in a row are a 9-sigma mean). Only where it sees smaller offsets
  than the jump test (:meth:`GpsGate.lookahead_worth`: noisy receivers) does the test
  look ahead: a fix is decided
  once the fixes ``group`` seconds after it are in (the smoother's window is longer), so the
  first fix of a burst is judged with the burst. It looks back too: a fix whose previous
  ``group`` seconds are inconsistent and which sits with them rather than with the estimate
  is a burst's tail (its look-ahead group, mostly clean fixes, would hide it), when the
  fix before it was rejected as multipath (a burst's start was caught). The test
  needs no state of its own: nothing can stay "in a burst" across an outage.

* **jump** (also counted as multipath) -- a fix against the previous one (at most
  ``jump_window`` s before): the step of the fixes minus the step of the estimated antenna,
  against both fixes' covariances plus the odometry's over the step. A precise receiver's
  burst starts with a step of many sigmas; the burst's offset is then followed fix to fix
  and the burst ends when the offset returns (under ``jump_gate / 4``), when a fix sits
  with the estimate within ``jump_gate / 4`` of ``P + R`` (the estimate, its uncertainty
  grown as it dead-reckons or already as large as the offset, cannot call the fix wrong:
  a "burst" opened by the estimate's own error never jumps back), when the fixes stop
  for longer than ``jump_window`` (an outage ends it: nothing is held across one), or
  after ``yield_after``. A noisy receiver's steps are too noisy for this test; the group
  test catches its bursts. Without odometry over the step (a slip, a locked or dead wheel)
  the estimated step is the motion model's, allowed ``blind_speed_sd`` over the fix period;
  and after a fault found later has unsettled the gate the test goes on (the estimate's
  position is in doubt, not its motion over one period), unless the fault cleared a burst
  in progress: then no step is judged until the gate settles again.

After ``yield_after`` s in which every fix was rejected, the gate accepts again (counted as
``yielded``): an estimate that is wrong and overconfident must not lock its only absolute
sensor out. Before the estimate has settled (``settle_fixes`` fixes used) every fix is used.

Pure and ROS-free; testable on synthetic fixes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import param

# sensor_msgs/NavSatStatus
STATUS_NAMES = {-1: "NO_FIX", 0: "FIX", 1: "SBAS_FIX", 2: "GBAS_FIX"}

# Reasons a fix is not used (counters, diagnostics, replay summary, metrics.json).
NO_FIX = "no fix"  # the receiver said so
NOT_FINITE = "not finite"
TOO_OLD = "too old"  # its keyframe has left the smoother's window (or it arrived far too late)
OUTLIER = "outlier"
MULTIPATH = "multipath"
REASONS = (NO_FIX, NOT_FINITE, TOO_OLD, OUTLIER, MULTIPATH)


@dataclass(frozen=True)
class GpsGateParams:
    gate: float = param(25.0, lo=1.0, hi=1e6, doc="reject one fix whose squared Mahalanobis innovation is above this "
                                                  "(chi-square, 2 dof: 25 is p = 4e-6)")
    group_gate: float = param(16.0, lo=1.0, hi=1e6,
                              doc="reject a fix when the mean innovation of it and the fixes of the next 'group' s "
                                  "is above this (chi-square, 2 dof: 16 is p = 3e-4)")
    group: float = param(1.0, lo=0.0, hi=2.5, unit="s",
                         doc="look-ahead of the multipath test; a fix is used this much later (0: no multipath test)")
    group_wait: float = param(0.5, lo=0.0, hi=2.0, unit="s",
                              doc="decide anyway this long after the group's end when no later fix came (outage)")
    jump_gate: float = param(25.0, lo=1.0, hi=1e6,
                             doc="a step between consecutive fixes this far (squared Mahalanobis) from the "
                                 "estimate's step starts a suspected burst")
    jump_window: float = param(2.0, lo=0.0, hi=60.0, unit="s",
                               doc="fixes further apart are not compared; a gap this long ends a burst")
    yield_after: float = param(30.0, lo=0.0, hi=1e4, unit="s",
                               doc="accept fixes again after this long with every fix rejected")
    settle_fixes: int = param(20, lo=0, hi=100000, doc="fixes used before the tests start")
    blind_speed_sd: float = param(1.5, lo=0.01, hi=50.0, unit="m/s",
                                  doc="the estimate's speed error without odometry (a slip, a locked or dead "
                                      "wheel): the jump test's allowance for its step between two fixes")
    min_std: Tuple[float, float, float] = param((0.5, 0.3, 0.01), lo=0.0, hi=100.0, unit="m",
                                                doc="smallest horizontal standard deviation believed for a fix of "
                                                    "status FIX, SBAS_FIX, GBAS_FIX (whatever it reports)")

    def status_floor(self, status: int) -> float:
        """Smallest variance [m^2] believed for a fix of ``status``."""
        return self.min_std[max(0, min(2, int(status)))] ** 2


@dataclass
class Fix:
    """One fix on its way into the smoother."""
    t: float  # [s] measurement time
    z: np.ndarray  # [m] east, north of the antenna (map frame)
    R: np.ndarray  # 2 x 2 reported (and floored) covariance of the fix, its white part [m^2]
    status: int


@dataclass
class Verdict:
    use: bool
    reason: str = ""  # one of REASONS when not used
    d2: float = math.nan  # the deciding test's squared Mahalanobis distance
    yielded: bool = False


def eigen_range(S: np.ndarray) -> Tuple[float, float]:
    """The smallest and largest eigenvalue of a symmetric 2 x 2 matrix (closed form: the
    gate asks at every update, and LAPACK's call costs more than the arithmetic)."""
    a, b, d = float(S[0, 0]), float(S[0, 1]), float(S[1, 1])
    mean, r = 0.5 * (a + d), math.hypot(0.5 * (a - d), b)
    return mean - r, mean + r


def mahalanobis2(nu: np.ndarray, S: np.ndarray) -> float:
    try:
        return float(nu @ np.linalg.solve(S, nu))
    except np.linalg.LinAlgError:
        return math.inf


class GpsGate:
    """Decides fixes (see module docstring). The caller supplies, per fix, its innovation
    against the current estimate and that estimate's covariance (antenna position and drift,
    map axes)."""

    def __init__(self, p: GpsGateParams) -> None:
        self.p = p
        self.used = 0
        self.rejecting_since: Optional[float] = None
        self.counts: Dict[str, int] = {r: 0 for r in REASONS}
        self.yielded = 0
        self.last_d2 = math.nan  # of the latest decided fix (diagnostics)
        self.last_reason = ""  # of the latest decided fix ("" when used)
        self.burst: Optional[np.ndarray] = None  # offset of the suspected burst so far [m]
        self.burst_R0 = np.zeros((2, 2))  # covariance of the last fix before the burst
        self.burst_Q = np.zeros((2, 2))  # of the estimated antenna's motion since
        self.burst_since = -math.inf
        self.last_fix_t = -math.inf
        self.bursts = 0
        self.ever_settled = False  # unsettled since by a fault, not new: steps still tell a jump
        self.decisions: list = []  # (t, used, reason, d2) since the last pop_decisions

    @property
    def settled(self) -> bool:
        return self.used >= self.p.settle_fixes

    def lookahead_worth(self, P: np.ndarray, R: np.ndarray, n: int) -> bool:
        """Whether waiting for the look-ahead group can catch a burst the jump test cannot:
        the smallest offset the group test sees (``group_gate`` over ``P + R / n``) against
        the smallest the jump test sees (``jump_gate`` over two fixes' ``2 R``). A precise
        receiver's bursts are jumps of many sigmas: waiting would only delay its fixes (and
        the newest estimate would ride a second on odometry for nothing)."""
        if not self.settled or self.p.group <= 0.0:
            return False
        d_group = self.p.group_gate * eigen_range(P + R / max(1, n))[1]
        d_jump = self.p.jump_gate * eigen_range(2.0 * R)[0]
        return d_group < d_jump

    def unsettle(self, keep_burst_before: float = -math.inf) -> None:
        """The estimate is known to be wrong (a sensor fault found after the fact): use the
        next ``settle_fixes`` fixes untested, as at the start. A burst that began before
        ``keep_burst_before`` (the fault's earliest start: the estimate was still trusted when
        the fixes jumped) is no error of the estimate's and stays out until its fixes jump back
        (a wheel slip 4 s into a 5.4 m burst on rough ground let the burst's fixes in untested:
        the estimate jumped 5 m, the follower aborted)."""
        self.used = 0
        if self.burst is not None and self.burst_since >= keep_burst_before:
            # a burst that may be the estimate's own error: which side the fixes are on is
            # open, and so is whether their next step is a burst's start or its end. No step
            # is judged until the gate settles again (judged, a 4.6 m burst's jump back 0.4 s
            # after the slip was found held the right fixes out: the estimate ran 10 m off)
            self.burst = None
            self.ever_settled = False
        self.rejecting_since = None

    def skip(self, reason: str, t: float = math.nan) -> None:
        """Count a fix of time ``t`` that never reached the tests (no fix, not finite, too old)."""
        self.counts[reason] += 1
        self._record(t, False, reason, math.nan)

    MAX_DECISIONS = 100_000  # kept until popped (a node that never pops them keeps the newest)

    def _record(self, t: float, used: bool, reason: str, d2: float) -> None:
        self.decisions.append((t, used, reason, d2))
        if len(self.decisions) > self.MAX_DECISIONS:
            del self.decisions[:len(self.decisions) - self.MAX_DECISIONS]

    def pop_decisions(self):
        """(fix time, used, reason, squared Mahalanobis distance) of every decision since the
        last call, in the order made: reason "" when used, "yielded" when used after
        yield_after s of rejections, else why not."""
        out, self.decisions = self.decisions, []
        return out

    def decide(self, t: float, nu: np.ndarray, P: np.ndarray, R: np.ndarray,
               group: Sequence[Tuple[np.ndarray, np.ndarray]] = (),
               step: Optional[Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = None,
               behind: Sequence[Tuple[np.ndarray, np.ndarray]] = ()) -> Verdict:
        """Decide the fix of time ``t``: innovation ``nu``, estimate covariance ``P``, fix
        covariance ``R``; ``group``: (innovation, fix covariance) of the fixes of the next
        ``group`` seconds, against the same estimate; ``step``: (fix step minus estimated
        antenna step since the previous fix, the previous fix's covariance, this fix's, the
        estimated motion's), None without a previous fix; ``behind``: (innovation, fix
        covariance) of the fixes of the previous ``group`` seconds, against the same estimate."""
        jumped = self._jump(t, step)
        if jumped and self.settled and mahalanobis2(nu, P + R) < self.p.jump_gate / 4.0:
            # The fix sits with the estimate, within what the estimate itself is unsure of:
            # whatever jumped, the estimate cannot tell the fix wrong. A burst born of the
            # estimate's own error (a wheel that slid, a heading that had wandered) never
            # "jumps back": it held every fix out for yield_after (30 s) while the estimate
            # dead-reckoned on the error that had opened it.
            self.burst = None
            jumped = False
        verdict = Verdict(False, MULTIPATH, math.nan) if jumped else self._test(nu, P, R, group, behind)
        if verdict.use:
            self.rejecting_since = None
        else:
            if self.rejecting_since is None:
                self.rejecting_since = t
            if t - self.rejecting_since > self.p.yield_after:  # lost, not misled: let the fixes back in
                self.rejecting_since = None
                self.yielded += 1
                verdict = Verdict(True, "", verdict.d2, yielded=True)
        if verdict.use:
            self.used += 1
        else:
            self.counts[verdict.reason] += 1
        self.last_reason = verdict.reason
        self.last_d2 = verdict.d2
        self._record(t, verdict.use, ("yielded" if verdict.yielded else "") if verdict.use else verdict.reason,
                     verdict.d2)
        return verdict

    def _jump(self, t: float, step) -> bool:
        """Whether the fix is inside a suspected burst that began with a jump."""
        gap = t - self.last_fix_t
        self.last_fix_t = t
        if self.burst is not None and (gap > self.p.jump_window or t - self.burst_since > self.p.yield_after):
            self.burst = None  # an outage, or too long: whatever it was, it is over
        if self.settled:
            self.ever_settled = True
        if step is None or (not self.ever_settled and self.burst is None) or gap > self.p.jump_window:
            # Until the estimate first settles, no step of it is trusted. Unsettled later by a
            # fault (a wheel slip, a dead wheel), the estimate's position is in doubt, not its
            # motion over one fix period: a multipath burst that begins then is still a jump
            # (rough ground at 3 m/s: a 5.5 m burst 1.4 s into a slip went in untested, the
            # estimate jumped 4 m and the follower aborted).
            return self.burst is not None
        d, R_prev, R, Q = step
        if self.burst is None:
            if mahalanobis2(d, R_prev + R + Q) > self.p.jump_gate:
                # the offset since the last good fix: that fix's noise, the motion's, the newest fix's
                self.burst, self.burst_R0, self.burst_Q, self.burst_since = d.copy(), R_prev, Q.copy(), t
                self.bursts += 1
                return True
            return False
        self.burst = self.burst + d
        self.burst_Q = self.burst_Q + Q
        if mahalanobis2(self.burst, self.burst_R0 + self.burst_Q + R) < self.p.jump_gate / 4.0:
            self.burst = None  # the fix jumped back
            return False
        return True

    def _group_d2(self, nu, P, R, group) -> Tuple[float, np.ndarray]:
        """Squared Mahalanobis distance of the mean innovation of the fix and ``group``, and that mean."""
        n = 1 + len(group)
        mean = (nu + sum(g[0] for g in group)) / n
        mean_R = (R + sum(g[1] for g in group)) / n
        return mahalanobis2(mean, P + mean_R / n), mean

    def _test(self, nu, P, R, group, behind=()) -> Verdict:
        if not self.settled:
            return Verdict(True)
        d2 = mahalanobis2(nu, P + R)
        if d2 > self.p.gate:
            return Verdict(False, OUTLIER, d2)
        worst = d2
        if group:
            d2a, _ = self._group_d2(nu, P, R, group)
            if d2a > self.p.group_gate:  # a burst begins here or goes on
                return Verdict(False, MULTIPATH, d2a)
            worst = max(worst, d2a)
        if behind and self.last_reason == MULTIPATH:
            # A burst's last fixes have clean fixes ahead of them: look back too, and reject
            # a fix that sits with an inconsistent past rather than with the estimate. Only
            # inside a burst whose start was caught (the previous fix was rejected as one):
            # a sustained offset without such a start is the estimate's error, not multipath.
            d2b, mean_b = self._group_d2(nu, P, R, behind)
            if d2b > self.p.group_gate and mahalanobis2(nu - mean_b, R) < mahalanobis2(nu, R):
                return Verdict(False, MULTIPATH, d2b)
        return Verdict(True, "", worst)

    def summary(self) -> str:
        """One line of the counts by reason, for diagnostics and summaries."""
        parts = [f"{n} {r}" for r, n in self.counts.items() if n]
        if self.yielded:
            parts.append(f"{self.yielded} accepted after {self.p.yield_after:g} s of rejections")
        return ", ".join(parts) if parts else "none"
