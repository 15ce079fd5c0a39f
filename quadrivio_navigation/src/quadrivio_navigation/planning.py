"""One interface for the planners: ``plan(start, goal, grid, budget) -> PlanResult``.

The implementation is chosen by ``PlannerParams.planner``: ``lattice`` (ARA* over
motion primitives, :mod:`.lattice`) or ``ompl`` (OMPL's sampling-based planners in
Reeds-Shepp or Dubins space, :mod:`.ompl_planner`). Both check the vehicle's footprint
(``vehicle.yaml``, grown by ``cost.padding``) against the same cost grid and return the
path in the map frame with the driving direction of every step.

Poses are ``(x, y, yaw)`` in the map frame [m, m, rad]. Before searching, the start and
the goal are checked: outside the map, in collision (with the cell that is hit) and
unreachable give a result with ``ok = False`` and a reason naming the problem. Unreachable
is decided for both planners before any search, in milliseconds: the pieces of free space
a circle of the footprint's width can move in (:meth:`Planner.regions`), start and goal in
different ones.

A :class:`Planner` keeps what depends only on the map (cost grid, primitives and their
swept cells, the heuristic's graph) between plans; :func:`plan` builds one per call.
ROS-free.
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import param

from .curves import wrap_angles
from .costmap import LETHAL, CostGrid, CostParams, Footprint, max_safe_slope, slope_grid
from .lattice import LatticeParams, LatticePlanner
from .maps import OccupancyGrid
from .mprim import GenerationParams, PrimitiveSet, check_for_vehicle, generate, read_mprim

Pose = Tuple[float, float, float]


@dataclass(frozen=True)
class OmplParams:
    planner: str = param("RRTConnect", doc="OMPL geometric planner (RRTConnect, RRTstar, InformedRRTstar, BITstar, "
                                          "ABITstar, PRMstar, LazyPRMstar, KPIECE1, BKPIECE1, RRT, SST, FMT)")
    simplify: float = param(0.2, lo=0.0, hi=60.0, unit="s", doc="time for path simplification (0: none)")
    range: float = param(30.0, lo=0.0, hi=1000.0, unit="m", doc="the planner's longest step (0: OMPL's default)")
    check_resolution: float = param(0.0, lo=0.0, hi=10.0, unit="m",
                                    doc="motion checking step (0: half a cell)")
    stop_at_first: bool = param(False, doc="optimising planners: return the first solution instead of using "
                                           "the whole budget")
    hand_over: float = param(0.3, lo=0.0, hi=1.0,
                             doc="when OMPL has found no path in this fraction of the budget, the lattice plans in "
                                 "the rest (said in the result's note); a path found in it OMPL improves for the "
                                 "whole budget; 0: OMPL alone, the whole budget. Sampling "
                                 "finds no way through cluttered woods (0 of 6 far-apart pairs in 2 s on a 400 m map "
                                 "at 1 m, 24 % occupied) where the lattice's search does")


LATTICE_EXHAUSTED = "no drivable path: every lattice motion from the start was searched"  # lattice.py's reason
MIN_FALLBACK = 1.0  # [s] OMPL's least time when the lattice hands a wedged start over to it


@functools.lru_cache(maxsize=8)
def _generated(p: GenerationParams) -> PrimitiveSet:
    """:func:`generate`, once per process for a set of parameters (about a second of CPU: every
    plan made it again, replans and a campaign worker's next run included). Read-only: the
    planners share it."""
    return generate(p)


@dataclass(frozen=True)
class PlannerParams:
    planner: str = param("lattice", choices=("lattice", "ompl"), doc="planning algorithm")
    budget: float = param(2.0, lo=0.01, hi=600.0, unit="s", doc="planning time budget")
    reverse: bool = param(True, doc="plan reverse motions (Reeds-Shepp) or forward only (Dubins)")
    reverse_cost: int = param(3, lo=1, hi=100, doc="reverse motions cost this many times their length "
                                                   "(SBPL's additionalactioncostmult of reverse primitives)")
    turning_radius: float = param(0.0, lo=0.0, hi=100.0, unit="m",
                                  doc="minimum turning radius (0: the vehicle's, L / tan(max wheel angle))")
    radius_margin: float = param(1.05, lo=1.0, hi=3.0, doc="plan with the turning radius times this (tracking margin)")
    seed: int = param(1, lo=0, hi=2 ** 31 - 1, doc="seed of the sampling planners")
    sample_step: float = param(0.1, lo=0.01, hi=5.0, unit="m", doc="spacing of the returned path's poses")
    cost: CostParams = param(CostParams())
    lattice: LatticeParams = param(LatticeParams())
    ompl: OmplParams = param(OmplParams())


# Bounds for runs that must repeat (the closed loop in one process, ROS in lockstep): the lattice
# stops at this many expansions instead of at its wall-clock budget, whose reach depends on the
# machine. About 2 s of the native search on one core of this machine. The orchard's searches reach
# eps 1 in 11 000-57 000; at 30 000 (the Python search's 3 s) some starts ended on their eps-3 path,
# 64 m with 7 cusps, where the vehicle was held between the trees
REPEATABLE_EXPANSIONS = 300000
# The wall-clock budget behind it: only the OMPL fallback of a wedged start uses it (it stops at
# its first solution), and a start with no way out must not hold a run for minutes
REPEATABLE_BUDGET = 60.0


def repeatable(p: PlannerParams) -> PlannerParams:
    """``p`` for a run that must repeat: the lattice bounded by expansions (``p``'s own
    ``lattice.max_expansions`` if set, else :data:`REPEATABLE_EXPANSIONS`), the wall-clock
    budget only behind it. OMPL's sampling planners stay bounded by time: a run planned with
    ``planner: ompl`` repeats only where they find their path before it."""
    lat = dataclasses.replace(p.lattice, max_expansions=p.lattice.max_expansions or REPEATABLE_EXPANSIONS)
    return dataclasses.replace(p, lattice=lat, budget=max(p.budget, REPEATABLE_BUDGET))


@dataclass
class PlanResult:
    ok: bool
    reason: str  # why it failed, "" on success
    planner: str
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (N, 3) map frame
    directions: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))  # +1/-1 from pose i to i+1
    cost: float = math.inf
    length: float = math.nan  # [m]
    time_to_first: float = math.nan  # [s] until the first solution
    planning_time: float = math.nan  # [s] the whole call
    expansions: int = 0  # lattice: states expanded; ompl: states in the planner's data
    solutions: List[Tuple[float, float]] = field(default_factory=list)  # (time, cost) of each improvement
    expanded: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # map frame, for plots
    goal_offset: Tuple[float, float] = (0.0, 0.0)  # [m, rad] of the path's end from the goal
    note: str = ""  # what the caller should know about a success (a hand-over from OMPL to the lattice)

    @property
    def cusps(self) -> int:
        return int(np.sum(self.directions[1:] != self.directions[:-1])) if len(self.directions) > 1 else 0


def path_length(poses: np.ndarray) -> float:
    return float(np.sum(np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1])))) if len(poses) > 1 else 0.0


class Planner:
    """The planners of one map: build once, plan many times."""

    def __init__(self, grid: OccupancyGrid, vehicle, p: PlannerParams, heights: Optional[Callable] = None,
                 rollover=None) -> None:
        """``heights(x, y)``: terrain height [m] at map-frame arrays (a DEM), for slope
        cost and slopes too steep to drive; ``rollover``: the roll-over monitor's
        ``RolloverParams`` that set that limit."""
        self.grid, self.vehicle, self.p = grid, vehicle, p
        self.footprint = Footprint.from_vehicle(vehicle, p.cost.padding)
        self.turning_radius = (p.turning_radius or vehicle.min_turning_radius) * p.radius_margin
        slope = slope_grid(grid, heights) if heights is not None else None
        limit = p.cost.max_slope
        if not limit and rollover is not None:
            limit = max_safe_slope(vehicle.static_stability_factor, rollover.warn_ratio, rollover.max_roll,
                                   rollover.warn_fraction)
        self.max_slope = limit or math.inf
        self.cost = CostGrid(grid, p.cost, slope, self.max_slope)
        self._lattice: Optional[LatticePlanner] = None
        self._ompl = None
        self._regions: Optional[Tuple[np.ndarray, int]] = None
        self.build_time = 0.0

    # ---------------------------------------------------------------- planners
    def primitives(self) -> PrimitiveSet:
        lp = self.p.lattice
        if lp.mprim_file:
            ps = read_mprim(lp.mprim_file)
            check_for_vehicle(ps, self.turning_radius / self.p.radius_margin, self.grid.resolution, lp.mprim_file)
            return ps
        return _generated(GenerationParams(self.turning_radius, self.grid.resolution, lp.headings, self.p.reverse,
                                           self.p.reverse_cost, lp.long_step))

    def lattice(self) -> LatticePlanner:
        if self._lattice is None:
            t = time.perf_counter()
            self._lattice = LatticePlanner(self.cost, self.primitives(), self.footprint, self.turning_radius,
                                           self.p.reverse, self.p.lattice, self.p.cost.cost_weight,
                                           self.p.reverse_cost)
            self._lattice._free_2d()
            self.build_time += time.perf_counter() - t
        return self._lattice

    def ompl(self):
        if self._ompl is None:
            from .ompl_planner import OmplPlanner

            t = time.perf_counter()
            self._ompl = OmplPlanner(self.cost, self.footprint, self.turning_radius, self.p.reverse,
                                     self.p.reverse_cost, self.p.cost.cost_weight)
            self.build_time += time.perf_counter() - t
        return self._ompl

    # ------------------------------------------------------------------ checks
    def check_pose(self, pose: Pose, what: str) -> str:
        """'' when ``pose`` is a valid start or goal, else what is wrong with it."""
        x, y, yaw = pose
        if not all(map(math.isfinite, pose)):
            return f"{what} ({x}, {y}, {yaw}) is not a finite pose"
        if not self.grid.contains(x, y):
            w, h = self.grid.size
            ox, oy, _ = self.grid.origin
            return (f"{what} ({x:.2f}, {y:.2f}) is outside the map ({w:.1f} m x {h:.1f} m from "
                    f"({ox:.2f}, {oy:.2f}))")
        gx, gy, gth = self.grid.to_grid_frame(x, y, yaw)
        rows, cols = self.cost.pose_cells(self.footprint, gx, gy, gth)
        hh, ww = self.cost.shape
        outside = (rows < 0) | (cols < 0) | (rows >= hh) | (cols >= ww)
        if outside.any():
            return f"{what} ({x:.2f}, {y:.2f}, {math.degrees(yaw):.0f} deg): the vehicle would stick out of the map"
        hit = self.cost.cost[rows, cols] == LETHAL
        if hit.any():
            r, c = rows[hit][0], cols[hit][0]
            cx, cy, _ = self.grid.to_map_frame((c + 0.5) * self.grid.resolution, (r + 0.5) * self.grid.resolution)
            value = int(self.grid.data[r, c])
            kind = "unknown" if value < 0 else ("too steep" if value < self.p.cost.lethal else "occupied")
            return (f"{what} ({x:.2f}, {y:.2f}, {math.degrees(yaw):.0f} deg) is in collision: the footprint covers "
                    f"{int(hit.sum())} blocked cells, e.g. an {kind} cell at ({cx:.2f}, {cy:.2f})")
        return ""

    def regions(self) -> Tuple[np.ndarray, int]:
        """(labels, count) of the pieces of free space the vehicle's body can move in: the
        cells where a circle of half the footprint's width (padding included) may be
        centred, 8-connected. A superset: a cell is in when a point of it could hold the
        circle (its centre within half a cell diagonal), so two poses in different pieces
        are certainly not connected by any path of any planner."""
        if self._regions is None:
            from scipy import ndimage

            t = time.perf_counter()
            res = self.grid.resolution
            free = self.cost.cost != LETHAL
            dist = ndimage.distance_transform_edt(free) * res  # cell centre to the nearest blocked cell's
            radius = 0.5 * (self.footprint.left + self.footprint.right)
            room = free & (dist > radius - 0.5 * math.sqrt(2.0) * res)
            labels, n = ndimage.label(room, structure=np.ones((3, 3), dtype=bool))
            self._regions = (labels, int(n))
            self.build_time += time.perf_counter() - t
        return self._regions

    def _region_of(self, pose: Pose) -> int:
        """The free-space piece of the footprint's centre at ``pose`` (0: none found)."""
        x, y, yaw = pose
        d = 0.5 * (self.footprint.front - self.footprint.rear)  # the centre, ahead of base_link
        gx, gy, _ = self.grid.to_grid_frame(x + d * math.cos(yaw), y + d * math.sin(yaw))
        labels, _ = self.regions()
        r, c = int(math.floor(gy / self.grid.resolution)), int(math.floor(gx / self.grid.resolution))
        if 0 <= r < labels.shape[0] and 0 <= c < labels.shape[1]:
            return int(labels[r, c])
        return 0

    def check_connected(self, start: Pose, goal: Pose) -> str:
        """'' when start and goal may be connected, else why not (different free-space pieces:
        no planner can find a path, so none should search its whole budget for one)."""
        a, b = self._region_of(start), self._region_of(goal)
        if a == 0 or b == 0 or a == b:
            return ""
        labels, n = self.regions()
        width = self.footprint.left + self.footprint.right
        return (f"the goal is unreachable: start and goal are in different pieces of free space (the map's free "
                f"space makes "
                f"{n} pieces a vehicle {width:.2f} m wide, padding included, can move in; the start's has "
                f"{int(np.count_nonzero(labels == a))} cells, the goal's {int(np.count_nonzero(labels == b))})")

    # -------------------------------------------------------------------- plan
    def plan(self, start: Pose, goal: Pose, budget: Optional[float] = None, planner: Optional[str] = None,
             cancelled: Callable[[], bool] = lambda: False, seed: Optional[int] = None) -> PlanResult:
        t0 = time.perf_counter()
        kind = planner or self.p.planner
        budget = self.p.budget if budget is None else budget
        for pose, what in ((start, "start"), (goal, "goal")):
            problem = self.check_pose(tuple(map(float, pose)), what)
            if problem:
                return PlanResult(False, problem, kind, planning_time=time.perf_counter() - t0)
        problem = self.check_connected(tuple(map(float, start)), tuple(map(float, goal)))
        if problem:  # in milliseconds, where a search would spend its whole budget
            return PlanResult(False, problem, kind, planning_time=time.perf_counter() - t0)
        gs = self.grid.to_grid_frame(*start)
        gg = self.grid.to_grid_frame(*goal)
        if kind == "lattice":
            r = self.lattice().plan(gs, gg, budget, cancelled)
            out = PlanResult(r.ok, r.reason, kind, cost=r.cost, time_to_first=r.time_to_first,
                             expansions=r.expansions, solutions=[(t, c) for t, c, _, _ in r.solutions])
            poses, dirs, expanded = r.poses, r.directions, r.expanded
            if not r.ok and r.reason.startswith(LATTICE_EXHAUSTED) and not cancelled():
                # start and goal are in one piece of free space (checked above), yet no chain of
                # primitives joins them: a start wedged between obstacles (a vehicle that stopped
                # askew in a lane), from which only motions shorter or tighter than the lattice's
                # get out. Reeds-Shepp sampling in the continuous space, in the rest of the budget.
                # its first solution (a way out, not the best one: the next replan improves on it)
                spent = time.perf_counter() - t0
                first = dataclasses.replace(self.p.ompl, stop_at_first=True)
                orr = self.ompl().plan(gs, gg, max(MIN_FALLBACK, budget - spent), first,
                                       self.p.seed if seed is None else seed, self.p.sample_step, cancelled)
                note = (f"the lattice found no chain of motions from the start in {spent:.2f} s; OMPL's Reeds-Shepp "
                        f"sampling found a way out")
                out = PlanResult(orr.ok, orr.reason if orr.ok else f"{r.reason}; then OMPL: {orr.reason}",
                                 "lattice+ompl", cost=orr.cost, time_to_first=spent + orr.time_to_first,
                                 expansions=r.expansions, solutions=[(spent + t, c) for t, c in orr.solutions],
                                 note=note if orr.ok else "")
                poses, dirs, expanded = orr.poses, orr.directions, r.expanded
        elif kind == "ompl":
            share = self.p.ompl.hand_over
            # a path found within the share goes on improving for the whole budget, as the lattice's does
            r = self.ompl().plan(gs, gg, budget, self.p.ompl, self.p.seed if seed is None else seed,
                                 self.p.sample_step, cancelled, first_budget=budget * (share if share > 0.0 else 1.0))
            out = PlanResult(r.ok, r.reason, kind, cost=r.cost, time_to_first=r.time_to_first,
                             expansions=r.states, solutions=r.solutions)
            poses, dirs, expanded = r.poses, r.directions, np.zeros((0, 2))
            if not r.ok and share > 0.0 and not cancelled():
                # a clear hand-over: the lattice's search, in what is left of the budget
                spent = time.perf_counter() - t0
                lr = self.lattice().plan(gs, gg, max(0.05, budget - spent), cancelled)
                note = f"OMPL found no path in {spent:.2f} s ({r.reason}); the lattice planned in the rest of the budget"
                out = PlanResult(lr.ok, lr.reason if lr.ok else f"{r.reason}; then the lattice: {lr.reason}",
                                 "ompl+lattice", cost=lr.cost, time_to_first=spent + lr.time_to_first,
                                 expansions=lr.expansions, solutions=[(spent + t, c) for t, c, _, _ in lr.solutions],
                                 note=note if lr.ok else "")
                poses, dirs, expanded = lr.poses, lr.directions, lr.expanded
        else:
            raise ValueError(f"unknown planner '{kind}' (lattice, ompl)")
        out.planning_time = time.perf_counter() - t0
        if not out.ok:
            return out
        x, y, th = self.grid.to_map_frame(poses[:, 0], poses[:, 1], poses[:, 2])
        out.poses = np.column_stack([x, y, wrap_angles(th)])
        out.directions = np.asarray(dirs, dtype=np.int8)
        if len(expanded):
            ex, ey, _ = self.grid.to_map_frame(expanded[:, 0], expanded[:, 1])
            out.expanded = np.column_stack([ex, ey])
        out.length = path_length(out.poses)
        end = out.poses[-1]
        out.goal_offset = (math.hypot(end[0] - goal[0], end[1] - goal[1]),
                           abs(math.atan2(math.sin(end[2] - goal[2]), math.cos(end[2] - goal[2]))))
        return out

    def path_collides(self, poses: np.ndarray) -> List[int]:
        """Indices of the poses (map frame) whose exact footprint touches a blocked cell."""
        return [i for i, (x, y, th) in enumerate(poses) if self.cost.collides(self.footprint, x, y, th)]


def plan(start: Sequence[float], goal: Sequence[float], grid: OccupancyGrid, budget: float, vehicle,
         params: PlannerParams = PlannerParams()) -> PlanResult:
    """Plan once (see :class:`Planner` to plan repeatedly on one map)."""
    return Planner(grid, vehicle, params).plan(tuple(start), tuple(goal), budget)
