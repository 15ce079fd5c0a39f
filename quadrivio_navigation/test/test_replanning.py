"""Replanning's pure parts (quadrivio_navigation.replanning): which local marks are new,
whether they block the path ahead, and the map with them added."""
import numpy as np

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.maps import OccupancyGrid
from quadrivio_navigation.replanning import blocked_reason, known_distance, merge_local, new_marks

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
