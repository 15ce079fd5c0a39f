"""OMPL planners in Reeds-Shepp (reverse allowed) or Dubins space, through ctypes.

Why not the ``ompl`` Python wheel (measured here, see the README): the pinned 2.0
bindings have neither ``ReedsSheppStateSpace`` nor ``DubinsStateSpace``, and OMPL's C++
never calls a Python subclass's ``distance``/``interpolate``, so a car-like space cannot
be written in Python; the 1.7.0 wheel has both spaces but aborts the interpreter at exit.
Debian's ``libompl-dev`` 1.5 has everything, so the planning core is a small C++ library
(``src/ompl_core.cpp``, built by catkin as ``libquadrivio_ompl.so``) with a C interface
that this module loads. ctypes releases the GIL while it plans, so a node stays
responsive; ``cancelled`` is polled by the planner's termination condition.

ROS-free.
"""

from __future__ import annotations

import ctypes
import math
import os
import threading
from dataclasses import dataclass, field
from typing import Callable, List, Optional, Tuple

import numpy as np

from .costmap import CostGrid, Footprint
from .native import candidates

_LIB = None
_LIB_LOCK = threading.Lock()
CANCELLED = ctypes.CFUNCTYPE(ctypes.c_int)  # a search's cancel callback


class OmplUnavailable(RuntimeError):
    """libquadrivio_ompl.so was not found or does not load (the workspace is not built)."""


def _candidates() -> List[str]:
    return candidates("libquadrivio_ompl.so")


def load_library():
    """The C core (loaded once)."""
    global _LIB
    with _LIB_LOCK:
        if _LIB is not None:
            return _LIB
        tried = []
        for path in _candidates():
            if os.path.isfile(path):
                try:
                    lib = ctypes.CDLL(path)
                    break
                except OSError as exc:
                    tried.append(f"{path}: {exc}")
        else:
            raise OmplUnavailable("libquadrivio_ompl.so not found (build the workspace: make setup)"
                                  + (f"; {'; '.join(tried)}" if tried else ""))
        c_double_p = ctypes.POINTER(ctypes.c_double)
        lib.qv_ompl_planners.restype = ctypes.c_char_p
        lib.qv_ompl_version.restype = ctypes.c_char_p
        lib.qv_map_create.restype = ctypes.c_void_p
        lib.qv_map_create.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.c_double, ctypes.c_double,
                                      ctypes.c_double, ctypes.c_double, ctypes.c_double]
        lib.qv_map_destroy.argtypes = [ctypes.c_void_p]
        lib.qv_map_pose_cost.restype = ctypes.c_int
        lib.qv_map_pose_cost.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_double]
        lib.qv_curve_length.restype = ctypes.c_double
        lib.qv_curve_length.argtypes = [ctypes.c_double] * 7 + [ctypes.c_int]
        lib.qv_dubins_length.restype = ctypes.c_double
        lib.qv_dubins_length.argtypes = [ctypes.c_double] * 7
        lib.qv_weighted_rs_cost.restype = ctypes.c_double
        lib.qv_weighted_rs_cost.argtypes = [ctypes.c_double] * 8
        lib.qv_ompl_plan.restype = ctypes.c_int
        lib.qv_ompl_plan.argtypes = [
            ctypes.c_void_p, ctypes.c_double, ctypes.c_int, ctypes.c_char_p, ctypes.c_double, ctypes.c_double,
            ctypes.c_double, ctypes.c_double, ctypes.c_double, ctypes.c_int, ctypes.c_double, ctypes.c_double,
            ctypes.c_uint, c_double_p, c_double_p, ctypes.c_double, ctypes.POINTER(ctypes.c_int),
            ctypes.POINTER(ctypes.c_int), c_double_p, ctypes.c_char_p, ctypes.c_int]
        lib.qv_ompl_fetch.restype = ctypes.c_int
        lib.qv_ompl_fetch.argtypes = [ctypes.c_void_p, c_double_p, ctypes.c_int]
        # the lattice's search (lattice.py, src/lattice_core.cpp)
        vp, i32, i64 = ctypes.c_void_p, ctypes.c_int, ctypes.c_int64
        lib.qv_lattice_create.restype = vp
        lib.qv_lattice_create.argtypes = [vp, i32, i32, i32, i32, i32, ctypes.c_double, i32, vp, vp, vp, vp, vp, vp,
                                          vp, vp, i32, i32, i32, ctypes.c_double, i32, ctypes.c_double,
                                          ctypes.c_double, vp, i32]
        lib.qv_lattice_destroy.argtypes = [vp]
        lib.qv_lattice_plan.restype = i32
        lib.qv_lattice_plan.argtypes = [vp, vp, vp, ctypes.c_double, ctypes.c_double, ctypes.c_double, i64,
                                        ctypes.c_double, vp, vp, i32, ctypes.c_double, ctypes.c_double, i64,
                                        ctypes.c_double, ctypes.c_double, ctypes.c_double, i32, CANCELLED, vp]
        lib.qv_lattice_fetch.argtypes = [vp] * 7
        lib.qv_grid_dijkstra.restype = i32
        lib.qv_grid_dijkstra.argtypes = [vp, i32, i32, ctypes.c_double, i32, vp]
        _LIB = lib
        return lib


def planners() -> Tuple[str, ...]:
    return tuple(load_library().qv_ompl_planners().decode().split(","))


def version() -> str:
    return load_library().qv_ompl_version().decode()


def curve_length(a, b, r: float, reverse: bool) -> float:
    """OMPL's Reeds-Shepp (or Dubins) distance between two poses (for cross-checks)."""
    return load_library().qv_curve_length(*map(float, a), *map(float, b), float(r), int(reverse))


def dubins_length(a, b, r: float) -> float:
    """The C++ core's own Dubins distance, the one its forward-only planner uses (for cross-checks)."""
    return load_library().qv_dubins_length(*map(float, a), *map(float, b), float(r))


def weighted_rs_cost(a, b, r: float, reverse_cost: float) -> float:
    """The C++ core's weighted Reeds-Shepp cost (for cross-checks with curves.rs_cost)."""
    return load_library().qv_weighted_rs_cost(*map(float, a), *map(float, b), float(r), float(reverse_cost))


@dataclass
class OmplResult:
    ok: bool
    reason: str
    poses: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    directions: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int8))
    cost: float = math.inf
    time_to_first: float = math.nan
    solve_time: float = math.nan
    simplify_time: float = math.nan
    length: float = math.nan
    states: int = 0
    solutions: List[Tuple[float, float]] = field(default_factory=list)


class OmplPlanner:
    """OMPL on one cost grid (grid frame); :meth:`plan` once per request."""

    def __init__(self, cost: CostGrid, fp: Footprint, turning_radius: float, reverse: bool,
                 reverse_cost: float = 3.0, cost_weight: float = 2.0) -> None:
        self.lib = load_library()
        self.r, self.reverse = turning_radius, reverse
        self.reverse_cost, self.cost_weight = reverse_cost, cost_weight
        data = np.ascontiguousarray(cost.cost, dtype=np.uint8)
        h, w = data.shape
        self.handle = self.lib.qv_map_create(data.ctypes.data, w, h, cost.res, fp.front, fp.rear, fp.left, fp.right)
        if not self.handle:
            raise ValueError("OMPL core refused the cost grid")

    def __del__(self) -> None:
        handle, self.handle = getattr(self, "handle", None), None
        if handle and self.lib is not None:
            self.lib.qv_map_destroy(handle)

    def pose_cost(self, x: float, y: float, th: float) -> int:
        return self.lib.qv_map_pose_cost(self.handle, x, y, th)

    def plan(self, start, goal, budget: float, p, seed: int, sample_step: float,
             cancelled: Callable[[], bool] = lambda: False, first_budget: Optional[float] = None) -> OmplResult:
        """``p``: :class:`quadrivio_navigation.planning.OmplParams`. Without a path by
        ``first_budget`` seconds (default: ``budget``) the search gives up; with one, it goes on
        improving it (restarts, or the optimising planner's own) until ``budget``."""
        if p.planner not in planners():
            return OmplResult(False, f"unknown OMPL planner '{p.planner}' (one of {', '.join(planners())})")
        flag = ctypes.c_int(0)
        done = threading.Event()

        def watch() -> None:  # turn the Python cancel callback into the flag C++ polls
            while not done.wait(0.02):
                if cancelled():
                    flag.value = 1
                    return

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        s = (ctypes.c_double * 3)(*map(float, start))
        g = (ctypes.c_double * 3)(*map(float, goal))
        n = ctypes.c_int(0)
        stats = (ctypes.c_double * 7)()
        msg = ctypes.create_string_buffer(512)
        try:
            rc = self.lib.qv_ompl_plan(self.handle, self.r, int(self.reverse), p.planner.encode(), float(budget),
                                       float(budget if first_budget is None else first_budget), float(p.simplify),
                                       float(p.range), float(p.check_resolution), int(p.stop_at_first),
                                       float(self.reverse_cost), float(self.cost_weight),
                                       int(seed) & 0xFFFFFFFF, s, g, float(sample_step), ctypes.byref(flag),
                                       ctypes.byref(n), stats, msg, len(msg))
        finally:
            done.set()
            watcher.join()
        if rc != 0:
            return OmplResult(False, msg.value.decode(errors="replace") or f"OMPL core error {rc}",
                              solve_time=stats[1], states=int(stats[5]) if math.isfinite(stats[5]) else 0)
        buf = np.zeros(4 * n.value, dtype=np.float64)
        got = self.lib.qv_ompl_fetch(self.handle, buf.ctypes.data_as(ctypes.POINTER(ctypes.c_double)), n.value)
        arr = buf[:4 * got].reshape(-1, 4)
        sol = [(stats[0], stats[6])]
        if abs(stats[3] - stats[6]) > 1e-9:
            sol.append((stats[1] + stats[2], stats[3]))
        return OmplResult(True, "", arr[:, :3].copy(), arr[:, 3].astype(np.int8), stats[3], stats[0], stats[1],
                          stats[2], stats[4], int(stats[5]), sol)
