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

import math
from dataclasses import dataclass, replace
from typing import Callable, List, Optional, Tuple

import numpy as np

from quadrivio_config import param

from .fields import inside
from .maps import OccupancyGrid as Grid
from .planning import path_length


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


def mark_discs(grid: Grid, points, radius: float, footprint=None, pose=None) -> Grid:
    """``grid`` with the cells whose centres lie within ``radius`` [m] of each map-frame
    point marked occupied (100), but for those under ``footprint`` (grown by a cell) at
    ``pose``: where the vehicle stands stays a valid start, and its way toward the points is
    closed."""
    from .costmap import Footprint

    data = grid.data.copy()
    res = grid.resolution
    n = int(math.ceil(radius / res))
    for x, y in points:
        gx, gy, _ = grid.to_grid_frame(float(x), float(y))
        r0, c0 = int(math.floor(gy / res)), int(math.floor(gx / res))
        rr, cc = np.meshgrid(np.arange(r0 - n, r0 + n + 1), np.arange(c0 - n, c0 + n + 1), indexing="ij")
        disc = (np.hypot((cc + 0.5) * res - gx, (rr + 0.5) * res - gy) <= radius) & \
            (rr >= 0) & (rr < grid.height) & (cc >= 0) & (cc < grid.width)
        if footprint is not None and pose is not None and disc.any():
            fp = Footprint(footprint.front + res, footprint.rear + res, footprint.left + res, footprint.right + res)
            mx, my, _ = grid.to_map_frame((cc[disc] + 0.5) * res, (rr[disc] + 0.5) * res)
            under = inside(fp, np.column_stack([mx, my]), *pose)
            idx = np.flatnonzero(disc)
            disc.flat[idx[under]] = False
        data[rr[disc], cc[disc]] = 100
    return replace(grid, data=data)


class HeldPoints:
    """Where the obstacle guard held the vehicle: the points it held it for (the nearest
    point of each held decision, in the map frame), gathered while a hold lasts and
    forgotten when the vehicle drives on. A replan because of the hold keeps
    ``held_clearance`` from them (:func:`mark_discs`): the orchard's lattice planned, from a
    vehicle standing askew 0.35 m (along its arc) from a tree, the same turn-around that began
    toward the tree, the guard would not let it creep there (its ``creep_margin`` is 0.45 m),
    and the two held each other for 140 s, a replan every 8.5 s. The points are not added to
    the map: the tree is in it, where the estimate puts it; this is how near the guard lets
    the vehicle come."""

    def __init__(self, limit: int = 64) -> None:
        self.points: List[Tuple[float, float]] = []
        self.limit = limit

    def update(self, held: bool, pose: Optional[Tuple[float, float, float]],
               nearest: Optional[Tuple[float, float]]) -> None:
        """A guard decision: ``held`` or not, the vehicle's ``pose`` (map) and the ``nearest``
        point it saw (base_link), either None when unknown."""
        if not held:
            self.points.clear()
            return
        if pose is None or nearest is None or not all(math.isfinite(a) for a in (*pose, *nearest)):
            return
        c, s = math.cos(pose[2]), math.sin(pose[2])
        p = (pose[0] + c * nearest[0] - s * nearest[1], pose[1] + s * nearest[0] + c * nearest[1])
        if any(math.hypot(p[0] - q[0], p[1] - q[1]) < 0.1 for q in self.points):
            return
        self.points.append(p)
        del self.points[:-self.limit]

    def near(self, x: float, y: float, within: float = 10.0) -> List[Tuple[float, float]]:
        return [q for q in list(self.points) if math.hypot(q[0] - x, q[1] - y) <= within]


def replan_start(poses: Optional[np.ndarray], current: Tuple[float, float, float], speed: float, lead_time: float,
                 collides: Callable[[np.ndarray], List[int]]) -> Tuple[np.ndarray, Tuple[float, float, float]]:
    """Where a replan starts: ``(the poses of the current path kept, the start pose)``.

    Standing (below 0.2 m/s) or without a path: no poses kept, the vehicle's pose. Moving:
    the vehicle drives on while the planner works, so the start is the pose of its current
    path ``speed x lead_time`` ahead (``lead_time``: the planning time expected and a
    margin), but 2 m short of the first pose that ``collides`` (indices of the colliding
    poses of an array) on the merged map; the path up to there is kept."""
    v = abs(speed)
    if v < 0.2 or poses is None or len(poses) < 2:
        return np.zeros((0, 3)), current
    i0 = int(np.argmin(np.hypot(poses[:, 0] - current[0], poses[:, 1] - current[1])))
    seg = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    s = np.concatenate([[0.0], np.cumsum(seg)])
    j = int(np.searchsorted(s, s[i0] + v * lead_time))
    j = min(j, len(poses) - 1)
    hits = collides(poses[i0:j + 1])
    if hits:
        j = i0 + max(0, hits[0] - int(round(2.0 / max(s[1] - s[0], 0.05))))  # 2 m short of it
    if j <= i0 + 1:
        return np.zeros((0, 3)), current
    return poses[i0:j], tuple(float(a) for a in poses[j])


def overtaken(prefix: np.ndarray, start, current: Optional[Tuple[float, float, float]]) -> bool:
    """Whether the vehicle at ``current`` is past a replan's start: more than 1 m from it
    while that start was where it stood, or beyond it along the kept ``prefix``."""
    if current is None:
        return False
    if not len(prefix):
        return bool(np.hypot(current[0] - start[0], current[1] - start[1]) > 1.0)
    pts = np.vstack([prefix[:, :2], [start[:2]]])
    return int(np.argmin(np.hypot(pts[:, 0] - current[0], pts[:, 1] - current[1]))) >= len(pts) - 1


def remaining_length(poses: Optional[np.ndarray], current: Tuple[float, float, float]) -> float:
    """Length [m] of the path ``poses`` from its pose nearest ``current`` to its end (0 without one)."""
    if poses is None or len(poses) < 2:
        return 0.0
    i0 = int(np.argmin(np.hypot(poses[:, 0] - current[0], poses[:, 1] - current[1])))
    return path_length(poses[i0:])


class DetourWait:
    """Drive round what blocks the path, or wait for it to go?

    The local layer cannot tell a person crossing the lane from a parked vehicle: both are
    marks on the path. A detour that adds little (within ``margin`` metres of what was left
    of the path) is taken at once. A longer one waits: the path stays as it is (the obstacle
    guard stops the vehicle short of what blocks it) until it clears, and the vehicle goes on;
    or until it has stayed blocked for ``wait`` seconds, and the detour is planned again, from
    where the vehicle then stands. A person crossing an orchard lane sent the vehicle round
    the orchard (94 m instead of 57) for the 3 s they took to cross; a vehicle parked in the
    lane costs the wait. ``wait`` 0: every detour at once.

    An episode runs from the first time the path is found blocked until a detour is taken
    (:meth:`clear`), or until the path, clear again (:meth:`resume`), has stayed clear for
    ``wait`` seconds: marks that flicker (a dog at the lane's edge, seen and not) do not make the
    wait start over."""

    def __init__(self, wait: float, margin: float) -> None:
        self.wait = wait
        self.margin = margin
        self.since: Optional[float] = None  # the path blocked since (this episode)
        self.cleared: Optional[float] = None  # the path clear again since (within the episode)
        self.waiting = False  # a detour was put off: the old path is kept until it clears

    def blocked(self, t: float) -> None:
        """The path is found blocked at ``t`` (the episode starts, if it had not)."""
        if self.since is None or (self.cleared is not None and t - self.cleared > self.wait):
            self.since = t
        self.cleared = None

    def take(self, t: float, extra: float) -> bool:
        """Take a detour that is ``extra`` metres longer than what is left of the path, at ``t``?
        False: wait (:attr:`waiting`)."""
        self.blocked(t)
        take = self.wait <= 0.0 or not extra > self.margin or t - self.since >= self.wait
        self.waiting = not take
        return take

    def left(self, t: float) -> float:
        """Seconds left to wait (0: the detour's turn)."""
        return 0.0 if self.since is None else max(0.0, self.wait - (t - self.since))

    def resume(self, t: float) -> None:
        """The path waited for is clear at ``t``: the vehicle goes on along it."""
        self.waiting = False
        self.cleared = t

    def clear(self) -> None:
        """A detour is taken: the episode ends."""
        self.since = None
        self.cleared = None
        self.waiting = False


@dataclass(frozen=True)
class PlannerNodeParams:
    """The planner node's own parameters (``config/planner.yaml``, beside :class:`.planning.PlannerParams`)."""
    map_file: str = param("", doc="plan on this map_server map instead of the map topic")
    frame_id: str = param("map", doc="planning frame")
    terrain_from_scenario: bool = param(True, doc="slope cost from the scenario's simulated terrain")
    check_rate: float = param(2.0, lo=0.0, hi=50.0, unit="Hz",
                              doc="how often the remaining path is checked against local_obstacles (0: never)")
    check_horizon: float = param(25.0, lo=1.0, hi=1000.0, unit="m", doc="how far along the path it is checked")
    retry: float = param(2.0, lo=0.1, hi=600.0, unit="s", doc="a blocked vehicle's planner tries again this often")
    held_replan: float = param(8.0, lo=0.5, hi=600.0, unit="s",
                               doc="replan from where the vehicle stands when the obstacle guard has held it this "
                                   "long on a path that is not blocked (an obstacle beside a tight turn)")
    replan_budget: float = param(5.0, lo=0.1, hi=600.0, unit="s",
                                 doc="planning budget of a replan from a standing vehicle (it waits anyway)")
    held_clearance: float = param(0.45, lo=0.0, hi=5.0, unit="m",
                                  doc="a replan because the guard held the vehicle keeps this far from the points it "
                                      "held it for (the guard's creep_margin: nearer, it lets the vehicle creep no "
                                      "further)")
    detour_wait: float = param(10.0, lo=0.0, hi=600.0, unit="s",
                               doc="a detour longer than the blocked path by more than detour_margin waits this long "
                                   "for the path to clear (the guard stops the vehicle short of what blocks it); "
                                   "0: every detour at once")
    detour_margin: float = param(5.0, lo=0.0, hi=10000.0, unit="m",
                                 doc="a detour adding at most this much to the blocked path is taken at once")
    known_tolerance: float = param(0.8, lo=0.0, hi=5.0, unit="m",
                                   doc="local marks this close to the map's obstacles are those obstacles (the marks "
                                       "lie where the estimated pose puts them: the localization's error included)")
