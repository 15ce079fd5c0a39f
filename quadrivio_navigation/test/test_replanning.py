"""Replanning's pure parts (quadrivio_navigation.replanning): which local marks are new,
whether they block the path ahead, and the map with them added."""
import numpy as np

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.maps import OccupancyGrid
from quadrivio_navigation.planning import path_length
import math

from quadrivio_navigation.fields import inside
from quadrivio_navigation.replanning import (DetourWait, HeldPoints, blocked_reason, known_distance, mark_discs,
                                             merge_local, new_marks, remaining_length)

FP = Footprint.from_vehicle(load_vehicle(), 0.15)
PATH = np.column_stack([np.arange(0.0, 30.0, 0.1), np.zeros(300), np.zeros(300)])


def static_map():
    data = np.zeros((100, 400), dtype=np.int8)  # 40 m x 10 m at 0.1, origin (-5, -5)
    data[80:85, 100:105] = 100  # a known post at (5.0-5.5, 3.0-3.5)
    return OccupancyGrid(data, 0.1, (-5.0, -5.0, 0.0))


def local_with(*points):
    data = np.zeros((200, 200), dtype=np.int8)  # 20 m square, origin (-2, -10)
    g = OccupancyGrid(data, 0.1, (-2.0, -10.0, 0.0))
    for x, y in points:
        r, c = g.cell_of(x, y)
        data[r, c] = 100
    return g


def test_a_mark_on_the_path_ahead_blocks_it():
    st = static_map()
    why = blocked_reason(PATH, (1.0, 0.0, 0.0), local_with((12.0, 0.2)), FP, 25.0, st, known_distance(st), 0.5)
    assert "blocked" in why
    x, y = (float(v) for v in why.split("at (")[1].rstrip(")").split(","))
    assert abs(x - 12.0) <= 0.1 and abs(y - 0.2) <= 0.1
    # the front edge reaches x = 12 when base_link is at 12 - front: about 9 m ahead of x = 1
    ahead = float(why.split("blocked ")[1].split(" m")[0])
    assert abs(ahead - (12.0 - FP.front - 1.0)) < 0.3


def test_marks_beside_behind_or_known_do_not_block():
    st = static_map()
    known = known_distance(st)
    assert blocked_reason(PATH, (1.0, 0.0, 0.0), local_with((12.0, 2.0)), FP, 25.0, st, known, 0.5) == ""
    assert blocked_reason(PATH, (15.0, 0.0, 0.0), local_with((10.0, 0.0)), FP, 25.0, st, known, 0.5) == ""
    assert blocked_reason(PATH, (1.0, 0.0, 0.0), local_with((17.0, 0.0)), FP, 5.0, st, known, 0.5) == ""
    # the known post's face, seen by the laser 0.2 m off its cells: not new
    assert len(new_marks(local_with((4.85, 3.2)), st, known, 0.5)) == 0
    assert len(new_marks(local_with((3.5, 3.2)), st, known, 0.5)) == 1


def test_merge_marks_the_static_cells():
    st = static_map()
    merged = merge_local(st, local_with((12.03, 0.27)))
    r, c = st.cell_of(12.03, 0.27)
    assert merged.data[r, c] == 100 and st.data[r, c] == 0
    assert int((merged.data >= 100).sum()) == int((st.data >= 100).sum()) + 1


def test_held_points_are_gathered_while_held_and_forgotten_after():
    h = HeldPoints()
    h.update(True, (10.0, 5.0, math.pi / 2), (2.0, 0.5))  # 2 m ahead, 0.5 m left of a vehicle facing +y
    h.update(True, (10.0, 5.0, math.pi / 2), (2.02, 0.5))  # the same point again: kept once
    h.update(True, None, (1.0, 0.0))  # no pose: nothing to place
    h.update(True, (10.0, 5.0, 0.0), (float("nan"), 0.0))  # NaN: nothing
    assert len(h.points) == 1
    assert h.points[0] == (np.float64(9.5), np.float64(7.0)) or np.allclose(h.points[0], (9.5, 7.0))
    assert h.near(9.0, 7.0, 1.0) and not h.near(0.0, 0.0, 1.0)
    h.update(False, (10.0, 5.0, 0.0), None)  # driving on
    assert h.points == []


def test_discs_close_the_way_toward_the_points_but_not_the_start():
    """A vehicle standing 0.35 m (its padded footprint's front) from a point: a disc of
    0.45 m marks the cells around the point, except those under the vehicle, so that the
    start stays valid and the way ahead is closed."""
    grid = OccupancyGrid(np.zeros((100, 100), dtype=np.int8), 0.1, (-5.0, -5.0, 0.0))
    pose = (0.0, 0.0, 0.0)
    point = (FP.front + 0.35, 0.0)
    out = mark_discs(grid, [point], 0.45, FP, pose)
    rows, cols = np.nonzero(out.data == 100)
    x, y, _ = grid.to_map_frame((cols + 0.5) * 0.1, (rows + 0.5) * 0.1)
    d = np.hypot(x - point[0], y - point[1])
    assert len(d) > 30 and d.max() <= 0.45 + 1e-9
    assert not inside(FP, np.column_stack([x, y]), *pose).any()  # the start is free
    assert np.any(np.abs(y) < 0.1) and x.min() < FP.front + 0.2  # the disc reaches a cell from the footprint
    assert grid.data.max() == 0  # the input is untouched
    # without a footprint the whole disc, and the map's edge clips it
    full = mark_discs(grid, [(-4.95, -4.95)], 0.45)
    assert int((full.data == 100).sum()) > 0 and full.data[0, 0] == 100


def test_the_length_left_is_from_the_pose_nearest_the_vehicle():
    assert math.isclose(path_length(PATH), 29.9, abs_tol=1e-9)
    assert math.isclose(remaining_length(PATH, (10.02, 0.4, 0.0)), 19.9, abs_tol=1e-9)
    assert remaining_length(PATH, (40.0, 0.0, 0.0)) == 0.0
    assert remaining_length(None, (0.0, 0.0, 0.0)) == path_length(PATH[:1]) == 0.0  # planning.path_length


def test_a_short_way_round_is_taken_at_once_a_long_one_after_the_wait():
    d = DetourWait(wait=10.0, margin=5.0)
    assert d.take(3.0, 4.9) and not d.waiting  # a swerve within the lane
    d.clear()
    d.blocked(20.0)  # the path found blocked; the replan comes back later
    assert not d.take(20.5, 53.0) and d.waiting  # round the orchard: wait
    assert math.isclose(d.left(21.0), 9.0)
    assert not d.take(29.9, 53.0)
    assert d.take(30.0, 53.0) and not d.waiting and d.left(30.0) == 0.0  # waited 10 s from the first sight
    assert DetourWait(wait=0.0, margin=5.0).take(0.0, 500.0)  # 0: every detour at once
    assert not DetourWait(10.0, 5.0).take(0.0, math.inf)  # no bound on the way round is a long one


def test_a_path_clear_again_ends_the_wait_only_once_it_stays_clear():
    """Marks that flicker (the dog at the lane's edge, seen and not) must not make the wait
    start over, or a vehicle could wait for ever for a way round."""
    d = DetourWait(wait=10.0, margin=5.0)
    assert not d.take(8.5, 58.0)
    d.resume(9.0)  # cleared: the vehicle goes on
    assert not d.waiting
    assert not d.take(9.5, 58.0) and math.isclose(d.left(9.5), 9.0)  # blocked again: the same episode
    d.resume(10.0)
    d.blocked(20.5)  # clear for over the wait: a new episode
    assert math.isclose(d.left(20.5), 10.0)
    d.clear()  # a way round taken
    assert d.since is None and d.left(99.0) == 0.0
