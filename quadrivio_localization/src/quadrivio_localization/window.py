"""A fixed-lag window over GTSAM's iSAM2 that keeps the chain in time order.

GTSAM's ``IncrementalFixedLagSmoother`` constrains the elimination order only by "to be
marginalised first, everything else after", and leaves the rest to COLAMD. On a chain of
keyframes COLAMD puts the root somewhere in the middle of the window, so every update
(which touches the newest keyframe) re-eliminated from there; and with more than 65 % of
the variables re-eliminated iSAM2 takes its batch step: every factor relinearised (each a
Python call for our custom factors) and the whole window eliminated, at every update.
Measured on the consumer scenario: 294 of 305 variables re-eliminated per update, 12 ms.

Here the variables an update re-eliminates are ordered by their stamps with CCOLAMD
constraint groups ("levels"), so the newest keyframe is the root: a new keyframe
re-eliminates the top of the tree only, a late factor (a GPS fix decided a second after
its measurement) the keyframes from its own to the newest.

Marginalisation goes by *chunks* of ``chunk`` s: once a whole chunk is older than
``newest - lag`` it leaves the window in one piece (the window spans ``lag`` to
``lag + chunk`` s). ``ISAM2.marginalizeLeaves`` needs the keys it removes to be leaves and
first in their cliques (GTSAM crashes, not throws, when they are not first), so every
re-elimination orders each chunk before the next. CCOLAMD wants no group number above
the number of variables it orders, of which only the keys of the new factors are certain:
the levels are one per chunk, and the newest stamps get a level each as far as that
budget goes (with a keyframe's dozen keys, the newest half second).

Should an update have had to leave older chunks in one shared level (a budget too small
for the chunks, which the smoother's one-second chunks never meet), the Bayes tree is
checked before those chunks leave, and re-ordered if need be (``repairs``).

Variables older than every new factor and than ``relinearize_span`` s keep their
linearisation point: relinearising one re-eliminates from it to the root, and the old end
of the window, settled, soon leaves it. Keys carry a stamp, as in GTSAM's fixed-lag
smoothers; a stamp given again for a key already in the window moves it.
"""

from __future__ import annotations

import math
import re
import tempfile
from typing import Dict, List, Optional

import gtsam


class FixedLagWindow:
    def __init__(self, lag: float, params: gtsam.ISAM2Params, chunk: float = 1.0, relinearize_span: float = 1.0) -> None:
        if not chunk > 0.0:
            raise ValueError(f"chunk must be > 0 s, got {chunk}")
        self.lag = lag
        self.chunk = chunk
        self.relinearize_span = relinearize_span
        self.isam = gtsam.ISAM2(params)
        self.stamps: Dict[int, float] = {}
        self.last_result: Optional[gtsam.ISAM2Result] = None
        self.marginalized = 0  # keys marginalised so far
        self.repairs = 0  # marginalisations that had to re-order the window first
        self._merged_upto = -math.inf  # newest stamp an update left in a shared level (order not assured)
        self._chunks: Dict[float, int] = {}  # stamp -> its chunk (levels() asks for every stamp at every update)

    def timestamps(self) -> Dict[int, float]:
        return dict(self.stamps)

    def _chunk(self, t: float) -> int:
        return int(math.floor(t / self.chunk + 1e-9))

    def levels(self, budget: int, reach: float) -> Dict[float, int]:
        """Ordering level (CCOLAMD constraint group) of every stamp in the window, in time
        order, at most ``max(budget, chunks from reach's)`` levels: one per chunk from
        ``reach``'s to the newest (those the update re-eliminates), one per older chunk for up
        to three chunks before (a clique straddling the reach brings older frontals along),
        one per stamp for the newest stamps, and level 0 shared by the chunks older still
        (the update leaves them be; should it re-eliminate them after all, their order is
        not assured, which is noted for :meth:`_marginalize` to check)."""
        stamps = sorted(set(self.stamps.values()))
        cache = self._chunks
        chunks = [cache[t] if t in cache else cache.setdefault(t, self._chunk(t)) for t in stamps]
        distinct = sorted(set(chunks))
        rc = self._chunk(reach)
        in_range = [c for c in distinct if c >= rc]
        older = [c for c in distinct if c < rc]
        budget = max(1, budget, len(in_range))
        free = budget - len(in_range)
        extra = min(len(older), 3, max(0, free - 1))
        rest = older[:len(older) - extra]
        if rest:  # these chunks share a level: if re-eliminated after all, their order is lost
            last = max(rest)
            self._merged_upto = max(self._merged_upto, max(t for t, c in zip(stamps, chunks) if c == last))
        base = 1 if rest and free >= 1 else 0
        rank = {c: 0 for c in rest}
        rank.update({c: base + i for i, c in enumerate(older[len(older) - extra:] + in_range)})
        count = base + extra + len(in_range)
        own = min(len(stamps), budget - count)
        out = {t: rank[c] for t, c in zip(stamps, chunks)}
        for i, t in enumerate(stamps[len(stamps) - own:]):
            out[t] = count + i
        return self._compact(out)

    @staticmethod
    def _compact(levels: Dict[float, int]) -> Dict[float, int]:
        """Renumber the levels 0, 1, 2, ... (no empty level in between)."""
        used = {v: i for i, v in enumerate(sorted(set(levels.values())))}
        return {t: used[v] for t, v in levels.items()}

    def update(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, stamps: Dict[int, float]) -> None:
        """Add ``graph`` and the new ``values`` (stamped by ``stamps``), solve, and
        marginalise the chunks older than the window."""
        self.stamps.update(stamps)
        if not self.stamps:
            self.last_result = self.isam.update(graph, values)
            return
        newest = max(self.stamps.values())
        reach = newest  # the oldest stamp a new factor touches
        observed = set()
        for i in range(graph.size()):
            f = graph.at(i)
            if f is not None:
                for k in f.keys():
                    observed.add(k)
                    reach = min(reach, self.stamps.get(k, newest))
        level = self.levels(len(observed), reach)
        held = min(reach, newest - self.relinearize_span)
        groups = gtsam.KeyGroupMap()
        hold = gtsam.KeyList()
        for k, t in self.stamps.items():
            lv = level[t]
            if lv:  # GTSAM's CCOLAMD puts a key without a group in group 0: the same order, fewer calls
                groups.insert2(k, lv)
            if t < held:
                hold.push_back(k)
        self.last_result = self.isam.update(graph, values, [], groups, hold)
        t_done = self._chunk(newest - self.lag) * self.chunk - 1e-9  # chunks ending before it are older than the lag
        old = [k for k, t in self.stamps.items() if t < t_done]
        if old:
            self._marginalize(old)

    def _marginalize(self, old: List[int]) -> None:
        suspect = self._merged_upto >= min(self.stamps[k] for k in old)
        if suspect and not self._removable(old):
            # Not leaves, or not first in their cliques: possible only where an update could
            # not order them (iSAM2's batch step with too small a budget of groups). Order
            # them now, at the cost of one re-elimination of the window, as GTSAM's own
            # fixed-lag smoother does at every marginalisation.
            self.repairs += 1
            groups, extra = gtsam.KeyGroupMap(), gtsam.KeyList()
            level = self.levels(len(self.stamps), min(self.stamps.values()))
            for k, t in self.stamps.items():
                groups.insert2(k, 0 if k in old else level[t] + 1)
            for k in old:
                extra.push_back(k)
            self.isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), [], groups, None, extra)
            self._merged_upto = -math.inf  # the whole window is in order now
            if not self._removable(old):
                raise RuntimeError("fixed-lag window: the keys leaving the window are not leaves of the Bayes tree")
        keys = gtsam.KeyList()
        for k in old:
            keys.push_back(k)
        self.isam.marginalizeLeaves(keys)
        for k in old:
            del self.stamps[k]
        remaining = set(self.stamps.values())
        self._chunks = {t: c for t, c in self._chunks.items() if t in remaining}
        self.marginalized += len(old)

    def _removable(self, old: List[int]) -> bool:
        """Whether ``ISAM2.marginalizeLeaves(old)`` is safe: every clique holding one of them
        as a frontal has them first, and no clique below them keeps others (GTSAM checks
        neither and corrupts its memory). The Bayes tree is read from its Graphviz dump, the
        only view of the cliques the Python wrapper gives (0.3 ms for a 3 s window)."""
        names = {gtsam.DefaultKeyFormatter(k) for k in old}
        with tempfile.NamedTemporaryFile(suffix=".dot") as f:
            self.isam.saveGraph(f.name)
            labels = re.findall(r'label="([^"]*)"', f.read().decode())
        for label in labels:
            front, _, sep = label.partition(":")
            frontals = [k.strip() for k in front.split(",") if k.strip()]
            parents = {k.strip() for k in sep.split(",") if k.strip()}
            marked = [k in names for k in frontals]
            if any(marked) and marked != sorted(marked, reverse=True):
                return False  # one of them after a key that stays
            if parents & names and not all(marked):
                return False  # a key that stays was eliminated before one of them
        return True

    def calculateEstimate(self) -> gtsam.Values:
        return self.isam.calculateEstimate()

    def solution(self) -> "Solution":
        """The current solution, read key by key (see :class:`Solution`)."""
        return Solution(self.isam, self.stamps)

    def marginalCovariance(self, key: int):
        return self.isam.marginalCovariance(key)


class Solution:
    """A window's solution, read key by key, with the ``exists``/``atPose2``/``atVector`` of
    ``gtsam.Values``. ``calculateEstimate()`` copies and retracts every key of the window
    (about 200) at every update, where the smoother reads a handful; iSAM2 computes a key's
    estimate alone the same way (its linearisation point retracted by its delta), so the
    values read are the same to the bit. Valid until the window's next update."""

    __slots__ = ("_isam", "_keys")

    def __init__(self, isam: gtsam.ISAM2, keys: Dict[int, float]) -> None:
        self._isam = isam
        self._keys = keys  # the window's keys: read-only here, changed only by an update

    def exists(self, key: int) -> bool:
        return key in self._keys

    def atPose2(self, key: int) -> gtsam.Pose2:
        return self._isam.calculateEstimatePose2(key)

    def atVector(self, key: int):
        return self._isam.calculateEstimateVector(key)
