"""Replanning around what the map does not hold: which marks of the local obstacle layer
are new, whether they block the remaining path, and the map with them added.

The local layer (:mod:`.local_layer`) also marks the map's own obstacles as the lasers
see them (a tree's bark, a wall's face): a mark within ``tolerance`` of an occupied map
cell is that obstacle, around which the path was already planned; only the others can
block it. A path is blocked when the footprint (with the planner's padding) at one of its
poses ahead of the vehicle, within ``horizon`` metres, holds a new mark.

Pure and ROS-free (the planner node calls it).
"""

from __future__ import annotations

from typing import Optional, Tuple

import numpy as np

from .fields import inside
from .maps import OccupancyGrid as Grid


def known_distance(static: Grid, lethal: int = 65) -> np.ndarray:
    """Each static cell's distance [m] to the nearest occupied one (0 on it)."""
    from scipy.ndimage import distance_transform_edt

    return distance_transform_edt(static.data < lethal) * static.resolution


def new_marks(local: Grid, static: Optional[Grid] = None, known: Optional[np.ndarray] = None,
              tolerance: float = 0.5) -> np.ndarray:
    """Map coordinates of the local grid's marked cells that the static map does not hold
    already (``known``: each static cell's distance to the map's obstacles; a mark within
    ``tolerance`` of one is that obstacle, seen): the planner planned around those."""
    rows, cols = np.nonzero(local.data >= 100)
    if len(rows) == 0:
        return np.zeros((0, 2))
    px, py, _ = local.to_map_frame((cols + 0.5) * local.resolution, (rows + 0.5) * local.resolution)
    pts = np.column_stack([np.asarray(px, float), np.asarray(py, float)])
    if static is None or known is None:
        return pts
    gx, gy, _ = static.to_grid_frame(pts[:, 0], pts[:, 1])
    col = np.floor(np.asarray(gx) / static.resolution).astype(int)
    row = np.floor(np.asarray(gy) / static.resolution).astype(int)
    h, w = known.shape
    inside = (row >= 0) & (col >= 0) & (row < h) & (col < w)
    keep = np.ones(len(pts), dtype=bool)
    keep[inside] = known[row[inside], col[inside]] > tolerance
    return pts[keep]


def blocked_reason(poses: np.ndarray, current: Tuple[float, float, float], local: Grid, footprint,
                   horizon: float, static: Optional[Grid] = None, known: Optional[np.ndarray] = None,
                   tolerance: float = 0.5) -> str:
    """Why the path from the pose nearest ``current`` on, for ``horizon`` metres, is blocked
    by the local grid's marks that the static map does not hold (footprint at each pose), or ''."""
    if len(poses) < 2:
        return ""
    pts = new_marks(local, static, known, tolerance)
    if len(pts) == 0:
        return ""
    i0 = int(np.argmin(np.hypot(poses[:, 0] - current[0], poses[:, 1] - current[1])))
    seg = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    ahead = np.flatnonzero((s >= s[i0]) & (s <= s[i0] + horizon))
    reach = footprint.circumscribed_radius
    for i in ahead[::2]:
        x, y, th = poses[i]
        near = pts[np.abs(pts[:, 0] - x) + np.abs(pts[:, 1] - y) < 2.0 * reach]
        if len(near) and inside(footprint, near, x, y, th).any():
            p = near[inside(footprint, near, x, y, th)][0]
            return (f"the path is blocked {s[i] - s[i0]:.1f} m ahead by an obstacle the map does not hold, at "
                    f"({p[0]:.1f}, {p[1]:.1f})")
    return ""


def merge_local(static: Grid, local: Grid, known: Optional[np.ndarray] = None, tolerance: float = 0.5) -> Grid:
    """The static map with the local grid's new marks (:func:`new_marks`) marked occupied
    (100). The map's own obstacles seen by the lasers are left as the map has them: their
    marks lie where the estimated pose puts them, and added they narrowed every passage by
    the localization's error (a vehicle standing between two trees became a start in
    collision)."""
    data = static.data.copy()
    pts = new_marks(local, static, known, tolerance)
    if len(pts):
        for x, y in pts:
            if static.contains(float(x), float(y)):
                r, c = static.cell_of(float(x), float(y))
                data[r, c] = 100
    return Grid(data, static.resolution, static.origin)
