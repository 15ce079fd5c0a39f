"""Both planners on hand-checkable maps: a corridor, a dead end that needs reversing, an
unreachable goal, bad requests; collision-free paths; same seed, same path; slopes."""
import dataclasses
import math

import numpy as np
import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import CostParams
from quadrivio_navigation.curves import check_curvature
from quadrivio_navigation.maps import OccupancyGrid
from quadrivio_navigation.planning import OmplParams, Planner, PlannerParams, plan
from quadrivio_navigation.synthetic_maps import Canvas, scattered, yard

VEHICLE = load_vehicle()


# The OMPL core is built by `make setup`; without it these tests fail (they do not skip).
PLANNERS = ["lattice", "ompl"]


def params(kind: str, **changes) -> PlannerParams:
    return dataclasses.replace(PlannerParams(planner=kind, budget=2.0), **changes)


def corridor_map() -> OccupancyGrid:
    """A 40 m x 12 m yard with a 3.2 m wide, 30 m long corridor walled along it."""
    cv = Canvas(-5.0, -6.0, 40.0, 12.0, 0.2)
    cv.box(15.0, 1.8, 30.0, 0.4)
    cv.box(15.0, -1.8, 30.0, 0.4)
    cv.border(0.4)
    return cv.grid()


def dead_end_map() -> OccupancyGrid:
    """A blind alley 2.6 m wide and 16 m deep off a yard: too narrow to turn."""
    return yard()


def collision_free(planner: Planner, poses: np.ndarray) -> bool:
    return planner.path_collides(poses) == []


@pytest.mark.parametrize("kind", PLANNERS)
def test_straight_corridor(kind):
    grid = corridor_map()
    planner = Planner(grid, VEHICLE, params(kind))
    r = planner.plan((-2.0, 0.0, 0.0), (32.0, 0.0, 0.0))
    assert r.ok, r.reason
    assert r.length == pytest.approx(34.0, rel=0.02)  # straight through
    assert r.cusps == 0 and (r.directions > 0).all()
    assert np.abs(r.poses[:, 1]).max() < 0.5  # stays in the middle
    assert r.goal_offset[0] < 1e-6 and r.goal_offset[1] < 1e-6  # ends exactly on the goal
    assert collision_free(planner, r.poses)
    assert check_curvature(r.poses, VEHICLE.min_turning_radius, tol=0.02) is None


@pytest.mark.parametrize("kind", PLANNERS)
def test_dead_end_needs_reversing(kind):
    grid = dead_end_map()
    planner = Planner(grid, VEHICLE, params(kind, budget=3.0))
    r = planner.plan((12.0, 0.0, 0.0), (-10.0, -5.0, math.pi / 2))
    assert r.ok, r.reason
    assert r.directions[0] < 0  # the only way out is backwards
    backwards = np.sum(np.hypot(*np.diff(r.poses[:, :2], axis=0).T)[r.directions[:-1] < 0])
    assert backwards > 10.0  # at least out of the alley
    assert collision_free(planner, r.poses)


@pytest.mark.parametrize("kind", PLANNERS)
def test_forward_only_cannot_leave_a_dead_end(kind):
    grid = dead_end_map()
    planner = Planner(grid, VEHICLE, params(kind, reverse=False, budget=1.0))
    r = planner.plan((12.0, 0.0, 0.0), (-10.0, -5.0, math.pi / 2))
    assert not r.ok and r.reason


@pytest.mark.parametrize("kind", PLANNERS)
def test_unreachable_goal(kind):
    cv = Canvas(-10.0, -10.0, 30.0, 20.0, 0.2)
    cv.box(10.0, 0.0, 8.0, 0.4)  # a walled pen around (10, 0)
    cv.box(10.0, -6.0, 8.0, 0.4)
    cv.box(6.0, -3.0, 0.4, 6.4)
    cv.box(14.0, -3.0, 0.4, 6.4)
    cv.border(0.4)
    planner = Planner(cv.grid(), VEHICLE, params(kind, budget=0.5))
    r = planner.plan((-5.0, 0.0, 0.0), (10.0, -3.0, 0.0))
    assert not r.ok
    if kind == "lattice":  # decided before searching
        assert "unreachable" in r.reason and r.expansions == 0


@pytest.mark.parametrize("start, goal, message", [
    ((-2.0, 0.0, 0.0), (60.0, 0.0, 0.0), "goal (60.00, 0.00) is outside the map"),
    ((-2.0, 0.0, 0.0), (15.0, 1.8, 0.0), "goal (15.00, 1.80, 0 deg) is in collision"),
    ((15.0, 1.5, 0.0), (-2.0, 0.0, 0.0), "start (15.00, 1.50, 0 deg) is in collision"),
    ((-2.0, 0.0, 0.0), (34.6, 0.0, 0.0), "stick out of the map"),
    ((-2.0, 0.0, 0.0), (math.nan, 0.0, 0.0), "not a finite pose"),
])
def test_bad_requests_say_what_is_wrong(start, goal, message):
    planner = Planner(corridor_map(), VEHICLE, params("lattice"))
    r = planner.plan(start, goal)
    assert not r.ok and message in r.reason, r.reason
    assert len(r.poses) == 0


def test_unknown_cells_are_a_parameter():
    grid = corridor_map()
    grid.data[:, 100:105] = -1  # an unknown band across the yard at x = 15..16 m
    blocked = Planner(grid, VEHICLE, params("lattice", budget=0.5)).plan((-2.0, 0.0, 0.0), (32.0, 0.0, 0.0))
    assert not blocked.ok
    free = dataclasses.replace(PlannerParams().cost, unknown="free")
    r = Planner(grid, VEHICLE, params("lattice", cost=free)).plan((-2.0, 0.0, 0.0), (32.0, 0.0, 0.0))
    assert r.ok


def random_pairs(planner: Planner, n: int, seed: int):
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        s = (rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(-math.pi, math.pi))
        g = (rng.uniform(-45, 45), rng.uniform(-45, 45), rng.uniform(-math.pi, math.pi))
        if math.hypot(s[0] - g[0], s[1] - g[1]) > 30 and not planner.check_pose(s, "s") and \
                not planner.check_pose(g, "g"):
            out.append((s, g))
    return out


@pytest.fixture(scope="module")
def field_planner():
    grid = scattered(size=100.0, res=0.2, seed=11, rocks=50, buildings=6)
    return Planner(grid, VEHICLE, params("lattice"))


@pytest.mark.parametrize("kind", PLANNERS)
def test_paths_are_collision_free_on_a_cluttered_field(field_planner, kind):
    for s, g in random_pairs(field_planner, 4, seed=5):
        r = field_planner.plan(s, g, budget=4.0, planner=kind)  # a property, not a speed: room for a loaded machine
        assert r.ok, r.reason
        assert collision_free(field_planner, r.poses)
        assert r.goal_offset[0] < 0.15 and r.goal_offset[1] < math.radians(12)
        steps = np.hypot(*np.diff(r.poses[:, :2], axis=0).T)
        assert steps.max() < 0.5  # a dense path the follower can use


@pytest.mark.wall  # OMPL's simplification stops at its time limit: a starved process simplifies less
def test_same_seed_same_path(field_planner):
    s, g = random_pairs(field_planner, 1, seed=9)[0]
    lattice_fixed = dataclasses.replace(PlannerParams().lattice, max_expansions=3000)
    p = Planner(field_planner.grid, VEHICLE, params("lattice", lattice=lattice_fixed, budget=30.0))
    a, b = p.plan(s, g), p.plan(s, g)
    assert a.ok and np.array_equal(a.poses, b.poses) and a.cost == b.cost
    first = dataclasses.replace(OmplParams(), stop_at_first=True)
    q = Planner(field_planner.grid, VEHICLE, params("ompl", ompl=first, seed=4))
    a, b = q.plan(s, g), q.plan(s, g)
    assert a.ok and np.array_equal(a.poses, b.poses)
    c = q.plan(s, g, seed=5)
    assert c.ok and not np.array_equal(a.poses, c.poses)  # another seed, another tree


def test_one_call_interface():
    r = plan((-2.0, 0.0, 0.0), (32.0, 0.0, 0.0), corridor_map(), 1.0, VEHICLE)
    assert r.ok and r.planner == "lattice" and r.time_to_first <= r.planning_time


def test_steep_slopes_are_obstacles_and_slopes_cost():
    """A ridge across the yard, steeper than the roll-over monitor's limit except in a notch."""
    from quadrivio_navigation.rollover import RolloverParams

    cv = Canvas(-10.0, -15.0, 40.0, 30.0, 0.5)
    cv.border(0.5)

    def heights(x, y):
        ridge = 4.0 * np.exp(-((x - 10.0) / 1.5) ** 2)  # about 1.2 rise over run on its flanks
        notch = np.clip((np.abs(y - 8.0) - 3.0) / 8.0, 0.0, 1.0)  # level for 3 m either side of y = 8
        return ridge * notch

    planner = Planner(cv.grid(), VEHICLE, params("lattice", budget=3.0), heights, RolloverParams())
    assert 0.3 < planner.max_slope < 0.5
    r = planner.plan((0.0, 0.0, 0.0), (20.0, 0.0, 0.0))
    assert r.ok, r.reason
    crossing = r.poses[np.argmin(np.abs(r.poses[:, 0] - 10.0))]
    assert abs(crossing[1] - 8.0) < 2.5  # through the notch, not over the ridge


def split_yard(gap: float) -> OccupancyGrid:
    """A 40 m x 20 m yard cut in two by a wall with one opening ``gap`` m wide (0: none)."""
    cv = Canvas(-20.0, -10.0, 40.0, 20.0, 0.2)
    if gap > 0:
        half = 0.5 * (20.0 - gap)
        cv.box(0.0, -10.0 + 0.5 * half, 0.4, half)
        cv.box(0.0, 10.0 - 0.5 * half, 0.4, half)
    else:
        cv.box(0.0, 0.0, 0.4, 20.0)
    cv.border(0.4)
    return cv.grid()


@pytest.mark.parametrize("kind", PLANNERS)
@pytest.mark.parametrize("gap", [0.0, 0.9])  # no opening; one narrower than the vehicle (1.2 m + padding)
def test_a_start_and_goal_in_different_pieces_are_refused_before_any_search(kind, gap):
    planner = Planner(split_yard(gap), VEHICLE, params(kind, budget=30.0))
    r = planner.plan((-10.0, 0.0, 0.0), (10.0, 0.0, 0.0))
    assert not r.ok and "unreachable: start and goal are in different pieces of free space" in r.reason, r.reason
    assert r.expansions == 0 and r.planning_time < 5.0  # no 30 s search (measured ~ms: bench)
    labels, n = planner.regions()
    assert n >= 2


@pytest.mark.parametrize("kind", PLANNERS)
def test_a_wide_enough_opening_joins_the_pieces(kind):
    planner = Planner(split_yard(4.0), VEHICLE, params(kind, budget=5.0))
    assert planner.check_connected((-10.0, 0.0, 0.0), (10.0, 0.0, 0.0)) == ""
    r = planner.plan((-10.0, 0.0, 0.0), (10.0, 0.0, 0.0))
    assert r.ok, r.reason
    assert collision_free(planner, r.poses)


def test_the_pieces_never_split_what_a_planner_connects():
    """A superset: on the scattered-obstacle map, every pair the lattice connects is in one piece."""
    grid = scattered(size=100.0, res=0.2, seed=4, rocks=60, buildings=8)
    planner = Planner(grid, VEHICLE, params("lattice", budget=2.0))
    found = 0
    for start, goal in random_pairs(planner, 8, 11):
        r = planner.plan(start, goal)
        if r.ok:
            found += 1
            a = planner._region_of(tuple(r.poses[0]))
            assert all(planner._region_of(tuple(p)) == a for p in r.poses[::5])
    assert found >= 4


def test_the_lattice_plans_from_a_start_just_clear_of_a_block():
    """On a 1 m map a start 0.21 m clear of a block (padding included) has its lattice state
    (its cell's centre) half a cell into the block: it used to be snapped there and refused
    ("every lattice motion from the start was searched") while OMPL planned from it. Now it
    joins the lattice by a curve from the exact start."""
    cv = Canvas(-10.0, -10.0, 40.0, 20.0, 1.0)
    cv.box(5.0, 3.0, 4.0, 2.0)  # a block whose lower edge is at y = 2.0
    cv.border(1.0)
    grid = cv.grid()
    cost = dataclasses.replace(CostParams(), padding=0.15)  # the geometry below is drawn for this padding
    fp = Planner(grid, VEHICLE, params("lattice", cost=cost)).footprint
    start = (5.3, 2.0 - fp.left - 0.21, 0.0)  # the footprint's left side 0.21 m below the block
    snapped = (5.5, 1.5, 0.0)  # its cell's centre
    for kind in PLANNERS:
        planner = Planner(grid, VEHICLE, params(kind, budget=3.0, cost=cost))
        assert planner.check_pose(start, "start") == "" and "collision" in planner.check_pose(snapped, "snapped")
        r = planner.plan(start, (20.0, -5.0, 0.0))
        assert r.ok, f"{kind}: {r.reason}"
        assert np.allclose(r.poses[0], start, atol=1e-6), f"{kind} starts at {r.poses[0]}, not {start}"
        assert collision_free(planner, r.poses)


def test_ompl_improves_a_path_found_in_its_share_for_the_whole_budget():
    """The hand-over share bounds OMPL's search for a first path, not its improvement: with a
    path early, RRTConnect restarts for the whole budget (as the lattice's ARA* improves for
    its), and what it returns is no dearer than its first path."""
    grid = scattered(size=40.0, res=0.2, seed=4, rocks=12, buildings=2)
    planner = Planner(grid, VEHICLE, params("ompl", budget=1.0, ompl=dataclasses.replace(OmplParams(), hand_over=0.3)))
    rng = np.random.default_rng(4)
    done = 0
    for _ in range(200):
        if done == 2:
            break
        s = (rng.uniform(-15, 15), rng.uniform(-15, 15), rng.uniform(-math.pi, math.pi))
        g = (rng.uniform(-15, 15), rng.uniform(-15, 15), rng.uniform(-math.pi, math.pi))
        if math.hypot(s[0] - g[0], s[1] - g[1]) < 15.0 or planner.check_pose(s, "s") or planner.check_pose(g, "g"):
            continue
        r = planner.plan(s, g)
        if not r.ok or r.time_to_first > 0.3:
            continue
        done += 1
        assert r.planner == "ompl" and r.planning_time >= 1.0, (r.planner, r.planning_time)
        assert r.cost <= r.solutions[0][1] + 1e-9
        assert collision_free(planner, r.poses)
    assert done == 2


def test_ompl_hands_over_to_the_lattice_in_the_rest_of_its_budget():
    """Where sampling finds no way in its share of the budget (here a share of 6 ms, too short
    for any path through a 30 m passage), the lattice plans in the rest, and the result says so."""
    cv = Canvas(-20.0, -10.0, 60.0, 20.0, 0.2)
    cv.box(10.0, 6.3, 30.0, 10.0)  # a passage 2.6 m wide: the footprint with its padding is 1.5 m
    cv.box(10.0, -6.3, 30.0, 10.0)
    cv.border(0.4)
    grid = cv.grid()
    ompl_alone = Planner(grid, VEHICLE, params("ompl", budget=1.0,
                                               ompl=dataclasses.replace(OmplParams(), hand_over=0.0)))
    handed = Planner(grid, VEHICLE, params("ompl", budget=6.0, ompl=dataclasses.replace(OmplParams(), hand_over=0.001)))
    r = handed.plan((-15.0, 0.0, 0.0), (35.0, 0.0, 0.0))
    assert r.ok, r.reason
    assert r.planner == "ompl+lattice" and "OMPL found no path in" in r.note and "the lattice planned" in r.note
    assert collision_free(handed, r.poses) and r.planning_time < 12.0  # its 6 s budget, with room for a loaded machine
    assert ompl_alone.plan((-15.0, 0.0, 0.0), (35.0, 0.0, 0.0)).planner == "ompl"  # no hand-over when 0


def test_a_start_wedged_in_an_orchard_lane_is_handed_to_ompl():
    """Stopped askew in a 5 m lane (found in an orchard_blocked run: the vehicle ended a
    multi-cusp turn 70 deg off the lane's axis), no chain of the lattice's primitives leaves
    the start though the goal is in the same piece of free space: OMPL's Reeds-Shepp
    sampling plans in the rest of the budget, and the result says so."""
    import os

    from quadrivio_description.site import load_site
    from quadrivio_navigation.maps import load_map

    here = os.path.dirname(os.path.abspath(__file__))
    grid = load_map(os.path.join(here, "..", "..", "scenarios", "maps", "orchard.yaml"), load_site().local_frame())
    planner = Planner(grid, VEHICLE, params("lattice", budget=10.0))
    start, goal = (35.45, 8.33, -1.22), (30.0, 7.5, math.pi)
    lattice_alone = planner.lattice().plan(grid.to_grid_frame(*start), grid.to_grid_frame(*goal), 5.0)
    assert not lattice_alone.ok and "every lattice motion from the start" in lattice_alone.reason
    r = planner.plan(start, goal)
    assert r.ok, r.reason
    assert r.planner == "lattice+ompl" and "OMPL" in r.note
    assert r.planning_time < 8.0  # its first way out, not the rest of a long budget
    assert collision_free(planner, r.poses)
    assert r.goal_offset[0] < 0.15 and r.goal_offset[1] < math.radians(12)


@pytest.mark.parametrize("yaw", [math.pi, -math.pi, 3.14159265])
def test_ompl_takes_a_goal_facing_exactly_west(yaw):
    """A goal's yaw of exactly pi (atan2 of a quaternion facing west) left RRTConnect with no
    valid goal state; any representation of west plans."""
    cv = Canvas(-10.0, -10.0, 30.0, 20.0, 0.2)
    cv.border(0.4)
    planner = Planner(cv.grid(), VEHICLE, params("ompl", budget=3.0))
    r = planner.plan((0.0, 0.0, 0.0), (10.0, 0.0, yaw))
    assert r.ok and r.planner == "ompl", r.reason
    assert r.goal_offset[0] < 0.15 and r.goal_offset[1] < math.radians(12)


@pytest.mark.parametrize("native", [True, False])
def test_planners_share_the_primitives_and_their_swept_cells_and_plan_as_if_alone(native):
    """The primitives and their swept cells are built once per process (a second of a plan's
    CPU) and shared by planners on maps of other sizes: each binds its own copy to its grid, so
    the dead end planned after an open yard of another width gives the path a
    planner built from nothing gives."""
    import quadrivio_navigation.lattice as lattice_mod
    import quadrivio_navigation.planning as planning_mod

    fixed = dataclasses.replace(PlannerParams().lattice, max_expansions=20000, native=native)
    # bounded by expansions, never by the clock: the Python search of 20 000 states took over
    # 30 s on a loaded CI machine, stopped at another ARA* pass and gave another path
    p = params("lattice", lattice=fixed, budget=600.0)
    start, goal = (-10.0, 0.0, 0.0), (3.0, 0.0, math.pi)  # into the blind alley: reversing

    def dead_end():
        planner = Planner(dead_end_map(), VEHICLE, p)
        return planner, planner.plan(start, goal)

    planning_mod._generated.cache_clear()
    del lattice_mod._TEMPLATES[:]
    alone, ref = dead_end()
    cv = Canvas(-5.0, -6.0, 31.0, 12.0, 0.2)
    cv.border(0.4)
    corridor = Planner(cv.grid(), VEHICLE, p)
    assert corridor.cost.shape[1] != alone.cost.shape[1]  # another width: other flat offsets
    open_first = corridor.plan((0.0, 0.0, 0.0), (-2.0, 3.0, math.pi))
    assert open_first.ok, open_first.reason
    shared, again = dead_end()
    assert shared.lattice().ps is corridor.lattice().ps  # built once
    assert shared.lattice().checker is corridor.lattice().checker
    assert ref.ok, ref.reason
    assert again.ok and np.array_equal(again.poses, ref.poses) and again.cost == ref.cost
    open_again = corridor.plan((0.0, 0.0, 0.0), (-2.0, 3.0, math.pi))  # its own binding kept
    assert np.array_equal(open_again.poses, open_first.poses)


@pytest.mark.parametrize("res,padding", [(0.2, 0.35), (0.1, 0.0), (0.5, 0.6)])
def test_swept_cells_are_the_union_of_each_poses_cells(res, padding):
    """costmap.swept_cells, the lattice's swept footprints in blocks of poses, gives exactly the
    cells footprint_cells gives pose by pose, for every generated primitive (densified as the
    lattice does, from the start cell's centre) and for random scattered poses."""
    from quadrivio_navigation.costmap import Footprint, densify, footprint_cells, swept_cells
    from quadrivio_navigation.mprim import GenerationParams, generate

    fp = Footprint.from_vehicle(VEHICLE, padding)
    prims = generate(GenerationParams(3.5, res, 16, True, 3, 2.0))

    def by_pose(poses):
        return np.unique(np.vstack([np.column_stack(footprint_cells(fp, x, y, th, res)) for x, y, th in poses]), axis=0)

    for p in prims.primitives[::3]:
        dense = densify(p.poses, 0.5 * res, math.radians(3.0))
        poses = np.column_stack([0.5 * res + dense[:, 0], 0.5 * res + dense[:, 1], dense[:, 2]])
        assert np.array_equal(swept_cells(fp, poses, res), by_pose(poses)), p
    rng = np.random.default_rng(int(res * 10))
    poses = np.column_stack([rng.uniform(-20, 20, 37), rng.uniform(-20, 20, 37), rng.uniform(-7, 7, 37)])
    assert np.array_equal(swept_cells(fp, poses, res), by_pose(poses))
    assert swept_cells(fp, np.zeros((0, 3)), res).shape == (0, 2)
