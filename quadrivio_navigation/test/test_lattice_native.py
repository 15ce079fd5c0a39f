"""The lattice's search in C++ (src/lattice_core.cpp) against its Python reference
(LatticePlanner._search_python) on random maps and requests: the same algorithm, so the
same path, cost and expansions, pass for pass; and the speed it is there for."""

import dataclasses
import math

import numpy as np
import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.lattice import LatticeParams
from quadrivio_navigation.planning import Planner, PlannerParams
from quadrivio_navigation.synthetic_maps import Canvas, scattered

VEHICLE = load_vehicle()


def planners(grid, expansions: int, reverse: bool = True, padding=None, **lattice_changes):
    """The native and the Python lattice on one grid, bounded by expansions (not time)."""
    out = []
    for native in (True, False):
        lp = dataclasses.replace(LatticeParams(), native=native, max_expansions=expansions, **lattice_changes)
        p = PlannerParams(planner="lattice", budget=600.0, reverse=reverse, lattice=lp)
        if padding is not None:
            p = dataclasses.replace(p, cost=dataclasses.replace(p.cost, padding=padding))
        out.append(Planner(grid, VEHICLE, p))
    return out


def requests(planner: Planner, n: int, rng, half: float, min_dist: float):
    out = []
    while len(out) < n:
        s = (rng.uniform(-half, half), rng.uniform(-half, half), rng.uniform(-math.pi, math.pi))
        g = (rng.uniform(-half, half), rng.uniform(-half, half), rng.uniform(-math.pi, math.pi))
        if math.hypot(s[0] - g[0], s[1] - g[1]) > min_dist and not planner.check_pose(s, "s") and \
                not planner.check_pose(g, "g"):
            out.append((s, g))
    return out


def search(planner: Planner, s, g):
    """The lattice's own search (no OMPL fallback), in the grid frame."""
    return planner.lattice().plan(planner.grid.to_grid_frame(*s), planner.grid.to_grid_frame(*g), 600.0)


def same(a, b):
    assert a.ok == b.ok, (a.reason, b.reason)
    assert a.reason == b.reason
    assert a.expansions == b.expansions
    if a.ok:
        assert a.cost == pytest.approx(b.cost, rel=1e-9)
        assert a.epsilon == pytest.approx(b.epsilon, rel=1e-9)
        assert [s[3] for s in a.solutions] == [s[3] for s in b.solutions]  # expansions at each improvement
        assert [s[1] for s in a.solutions] == pytest.approx([s[1] for s in b.solutions], rel=1e-9)
        assert a.poses.shape == b.poses.shape
        assert np.allclose(a.poses, b.poses, atol=1e-9)
        assert np.array_equal(a.directions, b.directions)
        assert np.allclose(a.expanded, b.expanded)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_native_search_is_the_python_search_on_random_fields(seed):
    """Rocks and buildings on a 40 m field at 0.2 m, requests 10 m or more apart: ARA* from
    eps 3 down to 1 (or the expansion bound), reverse and forward-only."""
    grid = scattered(size=40.0, res=0.2, seed=seed, rocks=12, buildings=2)
    rng = np.random.default_rng(seed)
    for reverse in (True, False):
        nat, py = planners(grid, 4000, reverse)
        for s, g in requests(nat, 2, rng, 18.0, 10.0):
            same(search(nat, s, g), search(py, s, g))


def test_native_search_from_a_start_joined_by_connectors():
    """A start whose own lattice state collides (1 m cells): both join the lattice by the
    same connectors and find the same path."""
    cv = Canvas(-10.0, -10.0, 40.0, 20.0, 1.0)
    cv.box(5.0, 3.0, 4.0, 2.0)
    cv.border(1.0)
    grid = cv.grid()
    nat, py = planners(grid, 20000, padding=0.15)  # the geometry below is drawn for this padding
    start = (5.3, 2.0 - nat.footprint.left - 0.21, 0.0)
    assert nat.check_pose(start, "start") == "" and "collision" in nat.check_pose((5.5, 1.5, 0.0), "snapped")
    a, b = search(nat, start, (20.0, -5.0, 0.0)), search(py, start, (20.0, -5.0, 0.0))
    assert a.ok
    same(a, b)
    assert np.allclose(a.poses[0], nat.grid.to_grid_frame(*start), atol=1e-6)


def test_native_search_fails_alike():
    """An expansion bound too small, and no drivable path (forward only into a blind alley
    too narrow to turn in, facing out): the same verdicts."""
    cv = Canvas(-10.0, -10.0, 30.0, 20.0, 0.2)
    cv.box(5.0, 0.0, 0.4, 16.0)  # a wall across with 1.6 m gaps at its ends
    cv.border(0.4)
    grid = cv.grid()
    nat, py = planners(grid, 200)
    r = search(nat, (-5.0, 0.0, 0.0), (15.0, 0.0, math.pi))
    assert not r.ok and "200 expansions" in r.reason
    same(r, search(py, (-5.0, 0.0, 0.0), (15.0, 0.0, math.pi)))
    alley = Canvas(-10.0, -10.0, 30.0, 20.0, 0.2)
    alley.box(8.0, 1.6, 16.0, 0.4)
    alley.box(8.0, -1.6, 16.0, 0.4)
    alley.box(16.2, 0.0, 0.4, 3.6)
    alley.border(0.4)
    nat, py = planners(alley.grid(), 0, reverse=False)
    r = search(nat, (10.0, 0.0, 0.0), (-5.0, 5.0, 0.0))  # deep in the alley, facing its end
    assert not r.ok and "every lattice motion" in r.reason
    same(r, search(py, (10.0, 0.0, 0.0), (-5.0, 5.0, 0.0)))


def test_native_heuristic_is_scipys_dijkstra():
    """The 2-D heuristic from the C++ Dijkstra against scipy's on the same free cells."""
    grid = scattered(size=40.0, res=0.2, seed=7, rocks=15, buildings=3)
    nat, py = planners(grid, 0)
    free = np.argwhere(nat.lattice()._free_2d())
    for goal in free[np.random.default_rng(7).choice(len(free), 3)]:
        goal = tuple(int(v) for v in goal)
        a, b = nat.lattice().heuristic_2d(goal), py.lattice().heuristic_2d(goal)
        assert np.array_equal(np.isinf(a), np.isinf(b))
        assert np.isinf(a).any() and np.isfinite(a).sum() > 0.5 * a.size  # walled-in cells, and most reachable
        finite = np.isfinite(a)
        assert np.allclose(a[finite], b[finite], rtol=1e-12, atol=1e-12)
