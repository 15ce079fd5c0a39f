"""State-lattice planner: anytime repairing A* (ARA*) over SBPL-style motion primitives.

States are (cell, heading index). A primitive's cost is its length times its cost
multiplier (the reverse penalty) times ``1 + cost_weight * c / 254`` for the highest
cell cost ``c`` its swept footprint touches; a primitive whose footprint touches a
lethal cell or leaves the map is not a successor. The cells each primitive sweeps are
precomputed once, exactly (:func:`quadrivio_navigation.costmap.footprint_cells` at
poses every half cell and 3 deg), so a successor costs one array lookup.

Heuristic ``h = max(h_2d, h_nh)``:

* ``h_2d``: Dijkstra distance from the goal over the 8-connected free cells of the grid
  inflated by the footprint's inscribed radius (less a cell, so it never blocks a pose
  that is free), times ``cos(22.5 deg)`` (an 8-connected distance overestimates a
  straight line by up to 1 / cos(22.5 deg));
* ``h_nh``: the obstacle-free Reeds-Shepp (Dubins without reverse) length to the goal,
  within ``nh_radius`` of the goal (memoised per plan), else the straight-line distance.

Goal: expanded states within ``shot_radius`` of the goal try an analytic expansion, the
Reeds-Shepp curve to the exact goal pose, collision-checked through footprint cell
templates precomputed per heading (64) and sub-cell offset (4 x 4), grown by the
discretisation's worst case; the lattice state nearest the goal counts as reached too
(within half a cell and half a heading step).

ARA* (Likhachev, Gordon, Thrun, NIPS 2003): weighted A* with ``f = g + eps h`` from
``eps = initial_epsilon``, then ``eps`` lowered by ``epsilon_step`` and the search
repaired (states improved after being closed are kept in INCONS and re-opened) until
``eps = 1`` or the time budget ends; each pass's path is ``eps``-suboptimal.
ROS-free.
"""

from __future__ import annotations

import copy
import functools
import heapq
import math
import threading
import time
from dataclasses import dataclass
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from quadrivio_config import param

from . import curves
from .costmap import LETHAL, CostGrid, Footprint, densify, footprint_cells, swept_cells
from .mprim import PrimitiveSet

TWO_PI = 2.0 * math.pi
OCTILE_ADMISSIBLE = math.cos(math.pi / 8.0)
OVERHEAD_BINS = 72


@dataclass(frozen=True)
class LatticeParams:
    headings: int = param(16, lo=4, hi=64, doc="heading directions of the lattice")
    long_step: float = param(2.0, lo=0.1, hi=50.0, unit="m", doc="nominal length of the long straight primitive")
    mprim_file: str = param("", doc="SBPL .mprim file to use instead of generated primitives")
    initial_epsilon: float = param(3.0, lo=1.0, hi=100.0, doc="ARA*: heuristic inflation of the first search")
    epsilon_step: float = param(0.5, lo=0.01, hi=10.0, doc="ARA*: decrease of epsilon per improvement")
    shot_radius: float = param(12.0, lo=0.0, hi=1000.0, unit="m",
                               doc="try an analytic Reeds-Shepp expansion to the goal within this distance (0: never)")
    shot_every: int = param(4, lo=1, hi=1000, doc="analytic expansion on every n-th expansion within shot_radius")
    start_connect_radius: float = param(1.0, lo=0.0, hi=10.0, unit="m",
                                        doc="the exact start joins the lattice states of the cells within this, in its "
                                            "heading bin and the two beside it, by collision-free curves")
    start_connectors: int = param(12, lo=1, hi=1000, doc="... at most this many, the shortest curves first")
    nh_radius: float = param(15.0, lo=0.0, hi=1000.0, unit="m",
                             doc="use the obstacle-free non-holonomic distance as heuristic within this distance")
    max_expansions: int = param(0, lo=0, hi=10 ** 9, doc="stop after this many expansions (0: only the time budget); "
                                                         "a fixed count makes the result independent of the machine")
    shortcuts: int = param(100, lo=0, hi=100000, doc="tries at replacing runs of primitives by one free, cheaper "
                                                     "Reeds-Shepp curve after the search (seeded; 0: none)")
    native: bool = param(True, doc="search in the C++ core (src/lattice_core.cpp, about 100 times faster); "
                                   "false: the Python reference it is cross-tested against")


@dataclass
class SearchResult:
    ok: bool
    reason: str
    poses: np.ndarray  # (N, 3) grid frame
    directions: np.ndarray  # (N,) +1/-1 from pose i to i+1
    cost: float
    time_to_first: float  # [s]
    solutions: List[Tuple[float, float, float, int]]  # (time s, cost, epsilon, expansions) of each improvement
    expansions: int
    expanded: np.ndarray  # (M, 2) grid-frame positions of expanded states (for plots)
    epsilon: float  # bound of the returned path


START = -3  # the exact start, joined to the lattice states around it by connectors


def _fail(reason: str, expansions: int = 0, expanded: np.ndarray = np.zeros((0, 2))) -> SearchResult:
    return SearchResult(False, reason, np.zeros((0, 3)), np.zeros(0, np.int8), math.inf, math.nan, [], expansions,
                        expanded, math.inf)


class _Prims:
    """Primitives of one start heading as arrays for one vectorised collision lookup."""

    def __init__(self, prims, res: float, fp: Footprint) -> None:
        self.drow, self.dcol, self.k_end, self.base = [], [], [], []
        self.poses, self.dirs, self.cells = [], [], []
        self.extent = 0
        for p in prims:
            # footprint swept from the start cell's centre, in cells of that start cell
            dense = densify(p.poses, 0.5 * res, math.radians(3.0))
            cells = swept_cells(fp, np.column_stack([0.5 * res + dense[:, 0], 0.5 * res + dense[:, 1], dense[:, 2]]),
                                res)
            self.extent = max(self.extent, int(np.abs(cells).max()))
            self.cells.append(cells)
            self.drow.append(p.dy)
            self.dcol.append(p.dx)
            self.k_end.append(p.end_heading)
            self.base.append(p.length * p.cost_mult)
            self.poses.append(p.poses)
            self.dirs.append(p.directions)
        self.count = len(prims)

    def bind(self, pad_width: int, width: int) -> None:
        """Flat offsets of the swept cells in a padded grid ``pad_width`` wide, and of the
        end cells in the unpadded grid ``width`` wide."""
        sizes = [len(c) for c in self.cells]
        self.starts = np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64)
        self.offsets = np.concatenate([c[:, 0] * pad_width + c[:, 1] for c in self.cells]).astype(np.int64)
        self.dflat = [dr * width + dc for dr, dc in zip(self.drow, self.dcol)]


class PoseChecker:
    """Footprint cells for any pose from templates per heading bin and sub-cell offset,
    grown by the worst case of the binning so that a pose it passes is free. Checks
    many poses in one array lookup."""

    def __init__(self, fp: Footprint, res: float, bins: int = 64, sub: int = 4) -> None:
        self.res, self.bins, self.sub = res, bins, sub
        margin = res * math.sqrt(2.0) / (2 * sub) + fp.circumscribed_radius * math.pi / bins
        big = Footprint(fp.front + margin, fp.rear + margin, fp.left + margin, fp.right + margin)
        cells = []
        for b in range(bins):
            th = TWO_PI * b / bins
            for i in range(sub):
                for j in range(sub):
                    x, y = (j + 0.5) * res / sub, (i + 0.5) * res / sub
                    cells.append(np.column_stack(footprint_cells(big, x, y, th, res)))
        m = max(len(c) for c in cells)
        # pad every template to m cells by repeating its first cell
        self.rows = np.stack([np.concatenate([c[:, 0], np.full(m - len(c), c[0, 0])]) for c in cells])
        self.cols = np.stack([np.concatenate([c[:, 1], np.full(m - len(c), c[0, 1])]) for c in cells])
        self.extent = int(max(np.abs(self.rows).max(), np.abs(self.cols).max()))

    def cells(self, poses: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Rows and columns (P x m) of the cells under the grown footprint at each pose."""
        x, y, th = poses[:, 0] / self.res, poses[:, 1] / self.res, poses[:, 2]
        cx, cy = np.floor(x), np.floor(y)
        j = np.minimum(self.sub - 1, ((x - cx) * self.sub).astype(int))
        i = np.minimum(self.sub - 1, ((y - cy) * self.sub).astype(int))
        b = np.rint(th / TWO_PI * self.bins).astype(int) % self.bins
        t = (b * self.sub + i) * self.sub + j
        return self.rows[t] + cy.astype(int)[:, None], self.cols[t] + cx.astype(int)[:, None]


_TEMPLATES: List[tuple] = []  # (primitives, res, footprint, [_Prims per heading], PoseChecker), newest last
_TEMPLATES_KEPT = 4
_TEMPLATES_LOCK = threading.Lock()


def _templates(prims: PrimitiveSet, res: float, fp: Footprint) -> Tuple[List[_Prims], PoseChecker]:
    """The swept cells of ``prims`` per start heading (unbound: each planner binds its own
    copy to its grid's width) and the pose checker, for this primitive set object, cell size
    and footprint. They do not depend on the map: building them took a second of a plan's
    CPU (the orchard's), and a replan, or the next run of a campaign's worker, makes the same."""
    with _TEMPLATES_LOCK:
        for entry in _TEMPLATES:
            if entry[0] is prims and entry[1] == res and entry[2] == fp:
                return [copy.copy(pr) for pr in entry[3]], entry[4]
    built = [_Prims(prims.for_heading(k), res, fp) for k in range(prims.headings)]
    checker = PoseChecker(fp, res)
    with _TEMPLATES_LOCK:
        _TEMPLATES.append((prims, res, fp, built, checker))  # holds prims: its id is not reused meanwhile
        del _TEMPLATES[:-_TEMPLATES_KEPT]
    return [copy.copy(pr) for pr in built], checker


@functools.lru_cache(maxsize=8)
def turning_overhead(r: float, reverse: bool, reverse_cost: float, bins: int = OVERHEAD_BINS) -> Tuple[float, ...]:
    """Extra cost [m] of setting off towards a far goal with the heading ``alpha`` away from
    the direction to it, per ``alpha`` bin: the cheapest Reeds-Shepp word (reverse parts at
    the reverse cost; Dubins without reverse) to a goal 40 turning radii ``r`` ahead, whatever
    its heading, less the distance. It depends on nothing else, and took a quarter second of
    every plan (a replan's, a campaign run's): computed once per process."""
    far = 40.0 * r
    out = []
    for b in range(bins):
        alpha = TWO_PI * b / bins
        best = math.inf
        for j in range(16):
            beta = TWO_PI * j / 16
            if reverse:
                # the goal in the start's frame: rotate (far, 0) by -alpha
                c = curves.rs_cost(far * math.cos(alpha), -far * math.sin(alpha), beta - alpha, r, reverse_cost)
            else:
                c = curves.path_length(curves.dubins((0.0, 0.0, alpha), (far, 0.0, beta), r))
            best = min(best, c)
        out.append(max(0.0, best - far))
    return tuple(out)


class LatticePlanner:
    """ARA* over ``prims`` on a cost grid (grid frame: metres from cell (0, 0)'s corner)."""

    def __init__(self, cost: CostGrid, prims: PrimitiveSet, fp: Footprint, turning_radius: float, reverse: bool,
                 p: LatticeParams, cost_weight: float, reverse_cost: float) -> None:
        self.cg, self.ps, self.fp, self.p = cost, prims, fp, p
        self.reverse_cost = float(reverse_cost)
        self.r, self.reverse = turning_radius, reverse
        self.res = cost.res
        self.n = prims.headings
        self.h, self.w = cost.shape
        self.cost_weight = cost_weight
        # padded cost grid: LETHAL around the map so that swept cells never index outside
        self.prims, self.checker = _templates(prims, self.res, fp)
        extent = max(max(pr.extent for pr in self.prims), self.checker.extent) + 2
        self.pad = extent
        self.wp = self.w + 2 * extent
        padded = np.full((self.h + 2 * extent, self.wp), LETHAL, dtype=np.uint8)
        padded[extent:extent + self.h, extent:extent + self.w] = cost.cost
        self.flat = padded.ravel()
        for pr in self.prims:
            pr.bind(self.wp, self.w)
        self._graph = None
        self._free = None
        self.overhead = turning_overhead(self.r, self.reverse, self.reverse_cost)
        self._handle = None  # the native search (_native): one plan at a time (it keeps the results)
        self._native_lock = threading.Lock()

    # -------------------------------------------------------------- heuristic
    def _free_2d(self) -> np.ndarray:
        """The cells free in the grid inflated by the footprint's inscribed radius, less a
        cell (built once)."""
        if self._free is None:
            from scipy import ndimage

            radius = max(0.0, self.fp.inscribed_radius - self.res * math.sqrt(0.5) - 1e-6)
            dist = ndimage.distance_transform_edt(~self.cg.blocked) * self.res
            self._free = (dist >= radius) & ~self.cg.blocked
        return self._free

    def _graph_2d(self):
        """Sparse 8-connected graph of the free cells (built once; the Python heuristic's)."""
        if self._graph is None:
            from scipy.sparse import csr_matrix

            free = self._free_2d()
            h, w = free.shape
            idx = np.arange(h * w).reshape(h, w)
            src, dst, wt = [], [], []
            for dy, dx, c in ((0, 1, 1.0), (1, 0, 1.0), (1, 1, math.sqrt(2.0)), (1, -1, math.sqrt(2.0))):
                x0, x1 = max(0, -dx), w - max(0, dx)
                a, b = idx[0:h - dy, x0:x1], idx[dy:h, x0 + dx:x1 + dx]
                m = free[0:h - dy, x0:x1] & free[dy:h, x0 + dx:x1 + dx]
                src.append(a[m])
                dst.append(b[m])
                wt.append(np.full(int(m.sum()), c * self.res))
            g = csr_matrix((np.concatenate(wt), (np.concatenate(src), np.concatenate(dst))), shape=(h * w, h * w))
            self._graph = (g, free)
        return self._graph

    def heuristic_2d(self, goal_cell: Tuple[int, int]) -> np.ndarray:
        """Admissible 2-D distance [m] from every cell to the goal cell (inf: unreachable):
        Dijkstra over the free cells' 8-connected graph, in the C++ core when ``native``."""
        free = self._free_2d()
        r, c = goal_cell
        if not free[r, c]:  # cannot happen for a free goal pose (see the module docstring)
            return np.full(self.h * self.w, np.inf)
        if self.p.native:
            import ctypes

            from .ompl_planner import load_library

            mask = np.ascontiguousarray(free, dtype=np.uint8)
            out = np.empty(self.h * self.w)
            load_library().qv_grid_dijkstra(mask.ctypes.data_as(ctypes.c_void_p), self.h, self.w, self.res,
                                            r * self.w + c, out.ctypes.data_as(ctypes.c_void_p))
            return out * OCTILE_ADMISSIBLE
        from scipy.sparse.csgraph import dijkstra

        g, _ = self._graph_2d()
        return dijkstra(g, directed=False, indices=r * self.w + c) * OCTILE_ADMISSIBLE

    def _descent_direction(self, h2: np.ndarray) -> np.ndarray:
        """Per cell, the direction [rad] of the neighbour the 2-D shortest path to the goal
        continues through (where the heuristic falls fastest)."""
        hh, ww = self.h, self.w
        H = h2.reshape(hh, ww)
        P = np.pad(H, 1, constant_values=np.inf)
        best = np.full(H.shape, np.inf)
        ang = np.zeros(H.shape)
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                if dr == 0 and dc == 0:
                    continue
                nb = P[1 + dr:1 + dr + hh, 1 + dc:1 + dc + ww] + math.hypot(dr, dc) * self.res * OCTILE_ADMISSIBLE
                better = nb < best
                best[better] = nb[better]
                ang[better] = math.atan2(dr, dc)
        return ang.ravel()

    # ------------------------------------------------------------------ search
    def plan(self, start: Tuple[float, float, float], goal: Tuple[float, float, float], budget: float,
             cancelled: Callable[[], bool] = lambda: False) -> SearchResult:
        """Plan from ``start`` to ``goal`` (grid frame) within ``budget`` seconds."""
        t0 = time.perf_counter()
        deadline = t0 + budget
        n, res, w = self.n, self.res, self.w

        sc = (int(math.floor(start[1] / res)), int(math.floor(start[0] / res)))
        gc = (int(math.floor(goal[1] / res)), int(math.floor(goal[0] / res)))
        sk = int(round(start[2] / TWO_PI * n)) % n
        gk = int(round(goal[2] / TWO_PI * n)) % n
        h2 = self.heuristic_2d(gc)
        if not math.isfinite(h2[sc[0] * w + sc[1]]):
            return _fail("goal unreachable: no passage as wide as the vehicle connects the start to the goal")
        descent = self._descent_direction(h2)
        rc = self.reverse_cost
        r = self.r
        thetas = [TWO_PI * k / n for k in range(n)]

        def shortest(a, b, radius):
            return curves.reeds_shepp(a, b, radius, rc) if self.reverse else curves.dubins(a, b, radius)

        start_state = (sc[0] * w + sc[1]) * n + sk
        goal_state = (gc[0] * w + gc[1]) * n + gk
        # reaching the goal's lattice state counts with what it would take to get from
        # there to the exact goal, so that an exact analytic expansion wins a tie
        snap = ((gc[1] + 0.5) * res, (gc[0] + 0.5) * res, TWO_PI * gk / n)
        snap_cost = curves.path_cost(shortest(snap, goal, self.r), rc)
        g: Dict[int, float] = {start_state: 0.0}
        parent: Dict[int, Tuple[int, int]] = {}  # state -> (parent state, primitive index or -1)

        # A start whose own lattice state (its cell's centre, its heading bin) collides joins
        # the lattice by collision-free curves to the states around it, as the goal does by
        # analytic expansions: on a 1 m map a start 0.21 m clear of a block (padding
        # included) was snapped half a cell into it and refused.
        root = start_state
        connectors: Dict[int, list] = {}
        snapped = ((sc[1] + 0.5) * res, (sc[0] + 0.5) * res, thetas[sk])
        if self.cg.pose_cost(self.fp, *snapped) != LETHAL:  # the start's own state: as the search always did
            init = [start_state]
        else:
            root = START
            g = {START: 0.0}
            reach = max(1, int(math.ceil(self.p.start_connect_radius / res)))
            candidates = []
            for dr in range(-reach, reach + 1):
                for dc in range(-reach, reach + 1):
                    if dr * dr + dc * dc > reach * reach:
                        continue
                    row, col = sc[0] + dr, sc[1] + dc
                    if not (0 <= row < self.h and 0 <= col < w):
                        continue
                    for dk in (-1, 0, 1):
                        k = (sk + dk) % n
                        segs = shortest(tuple(start), ((col + 0.5) * res, (row + 0.5) * res, thetas[k]), r)
                        candidates.append((curves.path_cost(segs, rc), (row * w + col) * n + k, segs))
            # the shortest first; checked with the exact footprint (the lattice's own checker is
            # grown by its binning, which is what made a start this close to a block fail)
            candidates.sort(key=lambda e: e[0])
            for _, s2, segs in candidates:
                c = self._connector_cost(tuple(start), segs)
                if c is not None:
                    g[s2] = c
                    parent[s2] = (START, -3)
                    connectors[s2] = segs
                    if len(connectors) >= self.p.start_connectors:
                        break
            if not connectors:
                return _fail(f"no drivable path: no collision-free curve joins the start to the lattice within "
                             f"{self.p.start_connect_radius} m")
            init = list(connectors)
        max_exp = self.p.max_expansions or 10 ** 12
        if self.p.native:
            found = self._search_native(h2, descent, goal, goal_state, snap_cost, init, [g[s] for s in init], root,
                                        start, connectors, deadline - time.perf_counter(), cancelled,
                                        time.perf_counter() - t0)
        else:
            found = self._search_python(h2.tolist(), descent.tolist(), goal, goal_state, snap_cost, g, parent, root,
                                        start, connectors, init, t0, deadline, cancelled)
        return self._result(*found, max_exp, budget, start_state, cancelled)

    def _heuristics(self, h2: list, descent: list, goal):
        """``heur(s) -> (h, exact)`` and ``heur_exact(s)`` of one plan (see the module docstring)."""
        n, res, w = self.n, self.res, self.w
        rc, r = self.reverse_cost, self.r
        overhead = self.overhead
        obins = len(overhead)
        to_bin = obins / TWO_PI
        gx, gy, _ = goal
        nh_r2 = self.p.nh_radius ** 2
        thetas = [TWO_PI * k / n for k in range(n)]

        def heur(s: int) -> Tuple[float, bool]:
            """(h, exact): near the goal first a cheap lower bound (exact False), the
            curve's cost only once the state reaches the top of OPEN (lazy evaluation)."""
            cell, k = divmod(s, n)
            hv = h2[cell]
            row, col = divmod(cell, w)
            x, y = (col + 0.5) * res, (row + 0.5) * res
            d2 = (x - gx) ** 2 + (y - gy) ** 2
            d = math.sqrt(d2)
            if d2 <= nh_r2:
                return (hv if hv > d else d), False
            hv += overhead[int(round((thetas[k] - descent[cell]) * to_bin)) % obins]
            return (hv if hv > d else d), True

        def heur_exact(s: int) -> float:
            cell, k = divmod(s, n)
            row, col = divmod(cell, w)
            a = ((col + 0.5) * res, (row + 0.5) * res, thetas[k])
            segs = curves.reeds_shepp(a, goal, r, rc) if self.reverse else curves.dubins(a, goal, r)
            v = curves.path_cost(segs, rc)
            hv = h2[cell]
            return hv if hv > v else v

        return heur, heur_exact

    def _search_python(self, h2, descent, goal, goal_state, snap_cost, g, parent, root, start, connectors,
                       push_order, t0, deadline, cancelled):
        """ARA*'s passes in Python: the reference the native search is tested against."""
        n, res, w = self.n, self.res, self.w
        rc = self.reverse_cost
        gx, gy, gth = goal
        r = self.r
        shot_r2 = self.p.shot_radius ** 2
        thetas = [TWO_PI * k / n for k in range(n)]
        heur, heur_exact = self._heuristics(h2, descent, goal)

        def shortest(a, b, radius):
            return curves.reeds_shepp(a, b, radius, rc) if self.reverse else curves.dubins(a, b, radius)

        GOAL = -1
        shots: Dict[int, Tuple[int, list]] = {}
        eps = self.p.initial_epsilon
        counter = 0
        open_heap: List[Tuple[float, int, int]] = []
        in_open: Dict[int, float] = {}
        closed: set = set()
        incons: set = set()
        hcache: Dict[int, float] = {}
        exact: set = set()

        def hval(s: int) -> float:
            v = hcache.get(s)
            if v is None:
                v, ex = heur(s)
                hcache[s] = v
                if ex:
                    exact.add(s)
            return v

        def push(s: int) -> None:
            nonlocal counter
            f = g[s] + eps * hval(s)
            in_open[s] = f
            counter += 1
            heapq.heappush(open_heap, (f, counter, s))

        for s in push_order:
            push(s)
        flat, wp, pad = self.flat, self.wp, self.pad
        prims = self.prims
        weight = self.cost_weight / 254.0
        expansions = 0
        expanded_xy: List[Tuple[int, int]] = []
        solutions: List[Tuple[float, float, float, int]] = []
        best: Optional[Tuple[float, float]] = None  # (cost, eps)
        best_path = None
        max_exp = self.p.max_expansions or 10 ** 12
        timed_out = False
        shot_count = 0

        def goal_g() -> float:
            return g.get(GOAL, math.inf)

        while True:
            # ---- ImprovePath
            while open_heap:
                f, _, s = open_heap[0]
                if in_open.get(s) != f:  # stale entry
                    heapq.heappop(open_heap)
                    continue
                if goal_g() <= f:
                    break
                heapq.heappop(open_heap)
                if s not in exact:  # lazy heuristic: evaluate it now, re-queue if it rose
                    exact.add(s)
                    hx = heur_exact(s)
                    if hx > hcache[s]:
                        hcache[s] = hx
                        f2 = g[s] + eps * hx
                        in_open[s] = f2
                        counter += 1
                        heapq.heappush(open_heap, (f2, counter, s))
                        continue
                del in_open[s]
                closed.add(s)
                expansions += 1
                if (expansions & 255) == 0:
                    if time.perf_counter() > deadline or cancelled():
                        timed_out = True
                        break
                if expansions >= max_exp:
                    timed_out = True
                    break
                cell, k = divmod(s, n)
                row, col = divmod(cell, w)
                expanded_xy.append((row, col))
                gs = g[s]
                if s == goal_state and gs + snap_cost < goal_g():
                    g[GOAL] = gs + snap_cost
                    parent[GOAL] = (s, -1)
                    shots.pop(GOAL, None)
                # analytic expansion to the exact goal
                x, y = (col + 0.5) * res, (row + 0.5) * res
                if shot_r2 > 0 and (x - gx) ** 2 + (y - gy) ** 2 <= shot_r2:
                    shot_count += 1
                    if shot_count % self.p.shot_every == 1 or self.p.shot_every == 1:
                        segs = shortest((x, y, thetas[k]), goal, r)
                        c = self._shot_cost((x, y, thetas[k]), segs)
                        if c is not None and gs + c < goal_g():
                            g[GOAL] = gs + c
                            parent[GOAL] = (s, -2)
                            shots[GOAL] = (s, segs)
                pr = prims[k]
                vals = flat[(row + pad) * wp + (col + pad) + pr.offsets]
                worst = np.maximum.reduceat(vals, pr.starts).tolist()
                for j in range(pr.count):
                    cmax = worst[j]
                    if cmax == LETHAL:
                        continue
                    s2 = (cell + pr.dflat[j]) * n + pr.k_end[j]
                    g2 = gs + pr.base[j] * (1.0 + weight * cmax)
                    if g2 < g.get(s2, math.inf):
                        g[s2] = g2
                        parent[s2] = (s, j)
                        if s2 in closed:
                            incons.add(s2)
                        else:
                            push(s2)
            # ---- a solution of this pass
            if goal_g() < math.inf and (best is None or goal_g() < best[0] - 1e-9):
                elapsed = time.perf_counter() - t0
                # the bound actually achieved (ARA*'s eps')
                lows = [g[s] + hval(s) for s in list(in_open) + list(incons)]
                bound = min(eps, goal_g() / min(lows)) if lows and min(lows) > 0 else eps
                best = (goal_g(), bound)
                best_path = self._extract(parent, shots, g, root, GOAL, start, connectors)
                solutions.append((elapsed, goal_g(), bound, expansions))
            # ImprovePath returns with OPEN left only on a solution or a timeout, so without a
            # solution here the search is exhausted
            if timed_out or best is None or best[1] <= 1.0 + 1e-9 or eps <= 1.0 or not (open_heap or incons):
                break
            # ---- next pass: lower eps, re-open INCONS, re-key OPEN (by state number, as the
            # native search does: ties then break alike)
            eps = max(1.0, eps - self.p.epsilon_step)
            keys = sorted(in_open) + sorted(incons - in_open.keys())
            incons = set()
            closed = set()
            open_heap = []
            in_open = {}
            for s in keys:
                counter += 1
                f = g[s] + eps * hval(s)
                in_open[s] = f
                open_heap.append((f, counter, s))
            heapq.heapify(open_heap)
        return best_path, best, solutions, expansions, expanded_xy, timed_out

    def _search_native(self, h2: np.ndarray, descent: np.ndarray, goal, goal_state: int, snap_cost: float,
                       init: list, init_g: list, root: int, start, connectors, budget: float, cancelled,
                       offset: float):
        """ARA*'s passes in the C++ core (src/lattice_core.cpp): the same search as
        :meth:`_search_python`, its chain of states turned into edges here."""
        with self._native_lock:
            return self._search_native_locked(h2, descent, goal, goal_state, snap_cost, init, init_g, root, start,
                                              connectors, budget, cancelled, offset)

    def _search_native_locked(self, h2, descent, goal, goal_state, snap_cost, init, init_g, root, start, connectors,
                              budget, cancelled, offset):
        import ctypes

        from .ompl_planner import CANCELLED

        lib = self._native()
        h2 = np.ascontiguousarray(h2, dtype=np.float64)
        descent = np.ascontiguousarray(descent, dtype=np.float64)
        states = np.asarray(init, dtype=np.int64)
        gs = np.asarray(init_g, dtype=np.float64)
        stats = np.zeros(8)
        callback = CANCELLED(lambda: 1 if cancelled() else 0)
        p = self.p
        lib.qv_lattice_plan(self._handle, h2.ctypes.data, descent.ctypes.data, float(goal[0]), float(goal[1]),
                            float(goal[2]), int(goal_state), float(snap_cost), states.ctypes.data, gs.ctypes.data,
                            len(states), float(p.initial_epsilon), float(p.epsilon_step), int(p.max_expansions),
                            max(0.0, float(budget)), float(p.nh_radius), float(p.shot_radius), int(p.shot_every),
                            callback, stats.ctypes.data)
        expansions, cost, bound, timed_out = int(stats[0]), float(stats[1]), float(stats[2]), bool(stats[3])
        nchain, nsol, nexp, nshot = (int(v) for v in stats[4:8])
        chain_s = np.zeros(nchain, np.int64)
        chain_j = np.zeros(nchain, np.int32)
        chain_g = np.zeros(nchain)
        sols = np.zeros(4 * nsol)
        expanded = np.zeros(2 * nexp, np.int32)
        shot = np.zeros(2 * nshot)
        lib.qv_lattice_fetch(self._handle, *(a.ctypes.data_as(ctypes.c_void_p)
                                             for a in (chain_s, chain_j, chain_g, sols, expanded, shot)))
        solutions = [(offset + t, c, b, int(e)) for t, c, b, e in sols.reshape(-1, 4).tolist()]
        expanded_xy = expanded.reshape(-1, 2)
        if not nchain:
            return None, None, solutions, expansions, expanded_xy, timed_out
        segs = [(chr(int(k)), float(v)) for k, v in shot.reshape(-1, 2).tolist()]
        # the chain as (parent, primitive, state) links: a connector from the exact start, or none
        links = [(START, -3, int(chain_s[0]))] if root == START else []
        links += [(int(chain_s[i - 1]), int(chain_j[i]), int(chain_s[i])) for i in range(1, nchain)]
        g = {int(st): float(gv) for st, gv in zip(chain_s, chain_g)}
        edges = self._edges(links, g, start, connectors, segs)
        return edges, (cost, bound), solutions, expansions, expanded_xy, timed_out

    def _native(self):
        """The C++ search of this grid and primitive set (built once)."""
        if self._handle is None:
            import ctypes

            from .ompl_planner import load_library

            lib = load_library()
            prims = self.prims
            counts = np.array([pr.count for pr in prims], np.int32)
            dflat = np.array([d for pr in prims for d in pr.dflat], np.int64)
            k_end = np.array([k for pr in prims for k in pr.k_end], np.int32)
            base = np.array([b for pr in prims for b in pr.base], np.float64)
            cell_counts = np.array([len(c) for pr in prims for c in pr.cells], np.int32)
            offsets = np.ascontiguousarray(np.concatenate([pr.offsets for pr in prims]), dtype=np.int64)
            rows = np.ascontiguousarray(self.checker.rows, dtype=np.int32)
            cols = np.ascontiguousarray(self.checker.cols, dtype=np.int32)
            overhead = np.asarray(self.overhead, np.float64)
            flat = np.ascontiguousarray(self.flat, dtype=np.uint8)
            hp = len(flat) // self.wp
            keep = (counts, dflat, k_end, base, cell_counts, offsets, rows, cols, overhead, flat)
            ptr = [a.ctypes.data_as(ctypes.c_void_p) for a in keep]
            handle = lib.qv_lattice_create(ptr[9], hp, self.wp, self.pad, self.h, self.w, self.res, self.n, ptr[0],
                                           ptr[1], ptr[2], ptr[3], ptr[4], ptr[5], ptr[6], ptr[7], self.checker.bins,
                                           self.checker.sub, rows.shape[1], self.r, int(self.reverse),
                                           self.reverse_cost, self.cost_weight, ptr[8], len(overhead))
            if not handle:
                raise ValueError("the native lattice refused its arguments")
            self._lib, self._handle = lib, handle
        return self._lib

    def __del__(self):
        if getattr(self, "_handle", None):
            self._lib.qv_lattice_destroy(self._handle)
            self._handle = None

    def _result(self, best_path, best, solutions, expansions, expanded_xy, timed_out, max_exp: int, budget: float,
                start_state: int, cancelled) -> SearchResult:
        n, res, w = self.n, self.res, self.w
        ex = np.asarray(expanded_xy, dtype=float).reshape(-1, 2)
        expanded = np.column_stack([(ex[:, 1] + 0.5) * res, (ex[:, 0] + 0.5) * res]) if len(ex) else np.zeros((0, 2))
        if best_path is None:
            if timed_out:
                reason = (f"no path found within the {budget:.2f} s budget ({expansions} states expanded)"
                          if expansions < max_exp else f"no path found in {expansions} expansions")
                if cancelled():
                    reason = "cancelled"
            else:
                reason = "no drivable path: every lattice motion from the start was searched"
            return _fail(reason, expansions, expanded)
        cost = best[0]
        if not best_path:  # the start is the goal's lattice state
            cell, k = divmod(start_state, n)
            row, col = divmod(cell, w)
            poses, dirs = np.array([[(col + 0.5) * res, (row + 0.5) * res, TWO_PI * k / n]]), np.ones(1, np.int8)
        else:
            if self.p.shortcuts:
                best_path = self._shortcut(best_path, self.p.shortcuts)
                cost = sum(e[2] for e in best_path)
            poses, dirs = self._join(best_path)
        return SearchResult(True, "", poses, dirs, cost, solutions[0][0], solutions, expansions, expanded, best[1])

    def _shot_cost(self, start, segs) -> Optional[float]:
        """Cost of an analytic expansion, None when it collides or leaves the map."""
        poses, _ = curves.sample(start, segs, self.r, 0.5 * self.res)
        rows, cols = self.checker.cells(poses)
        # poses stay inside the map's padding: a curve from a state in the map to the goal
        # in the map reaches at most a turning diameter beyond them
        rows += self.pad
        cols += self.pad
        if rows.min() < 0 or cols.min() < 0 or rows.max() >= self.h + 2 * self.pad or cols.max() >= self.wp:
            return None
        worst = int(self.flat[rows * self.wp + cols].max())
        if worst == LETHAL:
            return None
        return curves.path_cost(segs, float(self.reverse_cost)) * (1.0 + self.cost_weight * worst / 254.0)

    def _connector_cost(self, start, segs) -> Optional[float]:
        """Cost of a curve from the exact start, checked with the exact footprint at every
        sample (not the lattice's grown templates); None when it collides or leaves the map."""
        poses, _ = curves.sample(start, segs, self.r, 0.5 * self.res)
        worst = 0
        for x, y, th in poses:
            c = self.cg.pose_cost(self.fp, float(x), float(y), float(th))
            if c == LETHAL:
                return None
            worst = max(worst, c)
        return curves.path_cost(segs, float(self.reverse_cost)) * (1.0 + self.cost_weight * worst / 254.0)

    def _extract(self, parent, shots, g, start_state: int, goal: int, start=None, connectors=None):
        """The path as edges: (start pose, poses along the edge, directions of its steps, cost)."""
        chain = []
        s = goal
        while s != start_state:
            p, j = parent[s]
            chain.append((p, j, s))
            s = p
        chain.reverse()
        return self._edges(chain, g, start, connectors, shots[goal][1] if goal in shots else None)

    def _edges(self, chain, g, start, connectors, shot):
        """Edges (start pose, poses, directions, cost) of ``(parent, primitive, state)`` links:
        -3 a connector from the exact start, -2 the analytic expansion ``shot``, -1 the goal's
        lattice state (no motion)."""
        n, res, w = self.n, self.res, self.w
        edges = []
        for p, j, s in chain:
            if j == -3:  # from the exact start to its first lattice state
                pp, d = curves.sample(tuple(start), connectors[s], self.r, 0.5 * res)
                edges.append([pp, np.asarray(d[:-1], dtype=np.int8), g[s]])
                continue
            cell, k = divmod(p, n)
            row, col = divmod(cell, w)
            x0, y0 = (col + 0.5) * res, (row + 0.5) * res
            if j >= 0:
                pr = self.prims[k]
                pp = pr.poses[j].copy()
                pp[:, 0] += x0
                pp[:, 1] += y0
                d = pr.dirs[j]
            elif j == -2:
                pp, d = curves.sample((x0, y0, TWO_PI * k / n), shot, self.r, 0.5 * res)
                d = d[:-1]
            else:
                continue  # the lattice goal state itself
            edges.append([pp, np.asarray(d, dtype=np.int8), g[s] - g[p]])
        return edges

    def _shortcut(self, edges, attempts: int):
        """Replace runs of edges by one Reeds-Shepp curve where that is free and cheaper (in
        the search's own cost), ``attempts`` random tries from a fixed seed: the lattice's
        zigzag between its 16 headings straightened, as OMPL's simplifier does."""
        rng = np.random.default_rng(0)
        rc = self.reverse_cost
        for _ in range(attempts):
            if len(edges) < 3:
                break
            i, j = sorted(rng.choice(len(edges) + 1, 2, replace=False).tolist())
            if j - i < 2:
                continue
            a = tuple(edges[i][0][0])
            b = tuple(edges[j][0][0]) if j < len(edges) else tuple(edges[-1][0][-1])
            segs = curves.reeds_shepp(a, b, self.r, rc) if self.reverse else curves.dubins(a, b, self.r)
            c = self._shot_cost(a, segs)
            old = sum(e[2] for e in edges[i:j])
            if c is None or c >= old - 1e-9:
                continue
            pp, d = curves.sample(a, segs, self.r, 0.5 * self.res)
            pp[-1] = b
            edges[i:j] = [[pp, np.asarray(d[:-1], dtype=np.int8), c]]
        return edges

    def _join(self, edges):
        poses = [edges[0][0]] + [e[0][1:] for e in edges[1:]]
        allp = np.vstack(poses)
        alld = np.concatenate([e[1] for e in edges])
        alld = np.concatenate([alld, alld[-1:]])
        allp[:, 2] = curves.wrap_angles(allp[:, 2])
        return allp, alld
