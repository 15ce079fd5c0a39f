"""The vehicle's footprint and the cost grid planners check it against.

The footprint is the body's rectangle from ``vehicle.yaml`` around ``base_link`` (the
rear axle centre): ``front = length - rear_overhang`` ahead, ``rear = rear_overhang``
behind, half the width to each side, each grown by ``padding``. A cell is touched by the
footprint at pose ``(x, y, theta)`` when the rectangle and the cell's square overlap,
decided exactly by the separating-axis test on the four axes of the two shapes::

    overlap along u  <=>  |u . (c - p) - m_u| <= h_u + (res / 2)(|u_x| + |u_y|)

for the rectangle's axes ``u`` (``p`` its reference point, ``m_u``/``h_u`` the centre
offset and half extent of its interval along ``u``) and the grid's axes (interval tests
of the bounding boxes). Poses are in the grid frame (metres from cell (0, 0)'s corner).

Cost grid: ``LETHAL`` (255) for cells the vehicle must not touch (occupied at or above
``lethal``, unknown when unknown counts as occupied, slopes beyond ``max_slope``), else
0..254 from the highest of the map's in-between values, the terrain's slope and the
inflation around obstacles, ``c = 254 (1 - d / inflation)`` for a cell ``d`` metres from
the nearest blocked one (as costmap_2d's inflation layer, linear); a motion's cost is its
length times ``1 + cost_weight * (highest cost it touches) / 254``, so that a path keeps
its distance from trees and walls where it can, and a small localization error does not
put the vehicle into them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from quadrivio_config import param

from .maps import OccupancyGrid

LETHAL = 255


@dataclass(frozen=True)
class Footprint:
    front: float  # [m] ahead of base_link
    rear: float  # [m] behind base_link
    left: float  # [m]
    right: float  # [m]

    @staticmethod
    def from_vehicle(vehicle, padding: float = 0.0) -> "Footprint":
        b = vehicle.body
        half = 0.5 * b.width
        return Footprint(b.length - b.rear_overhang + padding, b.rear_overhang + padding, half + padding,
                         half + padding)

    @property
    def inscribed_radius(self) -> float:
        """Largest circle about base_link inside the footprint [m]."""
        return min(self.front, self.rear, self.left, self.right)

    @property
    def circumscribed_radius(self) -> float:
        return math.hypot(max(self.front, self.rear), max(self.left, self.right))

    def corners(self, x: float, y: float, theta: float) -> np.ndarray:
        """The rectangle's corners (4 x 2) at pose (x, y, theta), counter-clockwise."""
        c, s = math.cos(theta), math.sin(theta)
        local = np.array([[self.front, -self.right], [self.front, self.left], [-self.rear, self.left],
                          [-self.rear, -self.right]])
        return np.column_stack([x + c * local[:, 0] - s * local[:, 1], y + s * local[:, 0] + c * local[:, 1]])


def footprint_cells(fp: Footprint, x: float, y: float, theta: float, res: float) -> Tuple[np.ndarray, np.ndarray]:
    """Rows and columns of every cell the footprint at (x, y, theta) overlaps (grid frame).
    :func:`swept_cells` repeats this arithmetic for blocks of poses: change both together
    (test_planning's test_swept_cells_are_the_union_of_each_poses_cells holds them equal)."""
    corners = fp.corners(x, y, theta)
    c0, r0 = np.floor(corners.min(axis=0) / res).astype(int)
    c1, r1 = np.floor(corners.max(axis=0) / res).astype(int)
    cols, rows = np.meshgrid(np.arange(c0, c1 + 1), np.arange(r0, r1 + 1))
    cx = (cols.ravel() + 0.5) * res - x
    cy = (rows.ravel() + 0.5) * res - y
    c, s = math.cos(theta), math.sin(theta)
    half = 0.5 * res * (abs(c) + abs(s))  # a cell's half extent along either rectangle axis
    along = c * cx + s * cy  # along the heading
    across = -s * cx + c * cy
    ok = (np.abs(along - 0.5 * (fp.front - fp.rear)) < 0.5 * (fp.front + fp.rear) + half - 1e-9) & \
         (np.abs(across - 0.5 * (fp.left - fp.right)) < 0.5 * (fp.left + fp.right) + half - 1e-9)
    return rows.ravel()[ok], cols.ravel()[ok]


def swept_cells(fp: Footprint, poses: np.ndarray, res: float) -> np.ndarray:
    """The cells (rows, columns: an (n, 2) array in row-major order, each once) that
    :func:`footprint_cells` gives for any of ``poses`` (K x 3, grid frame): the same
    arithmetic, pose by pose, over a block of candidate cells at once (a motion's swept
    footprint, for the lattice's templates; a single pose is cheaper through
    footprint_cells, which the planners' path checks call pose by pose)."""
    poses = np.asarray(poses, dtype=float)
    local = np.array([[fp.front, -fp.right], [fp.front, fp.left], [-fp.rear, fp.left], [-fp.rear, -fp.right]])
    blocks = []
    for k0 in range(0, len(poses), 16):  # 16 poses a block: a long motion's arrays stay a few MB
        part = poses[k0:k0 + 16]
        x, y = part[:, 0:1], part[:, 1:2]
        c = np.array([[math.cos(t)] for t in part[:, 2]])  # math's, as footprint_cells (numpy's may differ by an ulp)
        s_ = np.array([[math.sin(t)] for t in part[:, 2]])
        cx_ = x + c * local[:, 0] - s_ * local[:, 1]  # Footprint.corners, pose by pose
        cy_ = y + s_ * local[:, 0] + c * local[:, 1]
        c0 = np.floor(cx_.min(axis=1) / res).astype(int)
        c1 = np.floor(cx_.max(axis=1) / res).astype(int)
        r0 = np.floor(cy_.min(axis=1) / res).astype(int)
        r1 = np.floor(cy_.max(axis=1) / res).astype(int)
        cols = np.arange(c0.min(), c1.max() + 1)
        rows = np.arange(r0.min(), r1.max() + 1)
        gx = (cols + 0.5) * res  # cell centres, before each pose's own offset
        gy = (rows + 0.5) * res
        dx = gx[None, None, :] - x[:, :, None]  # (K, 1, C)
        dy = gy[None, :, None] - y[:, :, None]  # (K, R, 1)
        cc, ss = c[:, :, None], s_[:, :, None]
        half = 0.5 * res * (np.abs(cc) + np.abs(ss))
        along = cc * dx + ss * dy
        across = -ss * dx + cc * dy
        ok = (np.abs(along - 0.5 * (fp.front - fp.rear)) < 0.5 * (fp.front + fp.rear) + half - 1e-9) & \
             (np.abs(across - 0.5 * (fp.left - fp.right)) < 0.5 * (fp.left + fp.right) + half - 1e-9)
        ok &= (cols[None, None, :] >= c0[:, None, None]) & (cols[None, None, :] <= c1[:, None, None])
        ok &= (rows[None, :, None] >= r0[:, None, None]) & (rows[None, :, None] <= r1[:, None, None])
        r, q = np.nonzero(ok.any(axis=0))
        blocks.append(np.column_stack([rows[r], cols[q]]))
    if not blocks:
        return np.zeros((0, 2), dtype=int)
    return np.unique(np.vstack(blocks), axis=0)


def densify(poses: np.ndarray, step: float, angle_step: float = 0.05) -> np.ndarray:
    """Poses along a polyline of poses, no farther apart than ``step`` [m] and
    ``angle_step`` [rad], so that a footprint swept through them leaves no gaps."""
    poses = np.asarray(poses, float)
    if len(poses) < 2:
        return poses
    d = np.hypot(np.diff(poses[:, 0]), np.diff(poses[:, 1]))
    da = np.abs(np.diff(np.unwrap(poses[:, 2])))
    n = np.maximum(1, np.ceil(np.maximum(d / step, da / angle_step))).astype(int)
    out = [poses[:1]]
    th = np.unwrap(poses[:, 2])
    for i, k in enumerate(n):
        f = (np.arange(1, k + 1) / k)[:, None]
        a = np.array([poses[i, 0], poses[i, 1], th[i]])
        b = np.array([poses[i + 1, 0], poses[i + 1, 1], th[i + 1]])
        out.append(a + f * (b - a))
    return np.vstack(out)


@dataclass(frozen=True)
class CostParams:
    lethal: int = param(65, lo=1, hi=100, doc="map cells at or above this value are obstacles")
    unknown: str = param("occupied", choices=("free", "occupied"), doc="how unknown (-1) cells count")
    padding: float = param(0.35, lo=0.0, hi=5.0, unit="m", doc="margin added to each side of the footprint")
    cost_weight: float = param(2.0, lo=0.0, hi=100.0,
                               doc="a motion's cost grows by this factor times its highest cell cost (0..1)")
    inflation: float = param(1.0, lo=0.0, hi=50.0, unit="m",
                             doc="cells closer than this to an obstacle cost more, the closer the more (0: off)")
    slope_weight: float = param(1.0, lo=0.0, hi=100.0, doc="cell cost per unit of terrain slope (before clipping)")
    max_slope: float = param(0.0, lo=0.0, hi=2.0, unit="1",
                             doc="slopes (rise over run) above this are obstacles; 0: the roll-over monitor's "
                                 "warning limit")


class CostGrid:
    """Per-cell cost (uint8, LETHAL = blocked) in the grid frame of an occupancy grid."""

    def __init__(self, grid: OccupancyGrid, p: CostParams, slope: Optional[np.ndarray] = None,
                 max_slope: float = math.inf) -> None:
        self.grid = grid
        self.p = p
        self.res = grid.resolution
        d = grid.data.astype(np.int16)
        cost = np.zeros(d.shape, dtype=np.float64)
        between = (d > 0) & (d < p.lethal)
        cost[between] = d[between] / float(p.lethal)
        self.max_slope = max_slope
        if slope is not None:
            cost = np.maximum(cost, np.clip(slope * p.slope_weight, 0.0, 1.0))
        blocked = grid.blocked(p.unknown, p.lethal)
        if slope is not None:
            blocked |= slope > max_slope
        if p.inflation > 0.0 and blocked.any():
            from scipy import ndimage

            d = ndimage.distance_transform_edt(~blocked) * self.res - 0.5 * self.res  # to the blocked cell's edge
            cost = np.maximum(cost, np.clip(1.0 - d / p.inflation, 0.0, 1.0))
        c = np.rint(cost * 254.0).astype(np.uint8)
        c[blocked] = LETHAL
        self.cost = c
        self.blocked = blocked

    @property
    def shape(self) -> Tuple[int, int]:
        return self.cost.shape  # type: ignore[return-value]

    def pose_cells(self, fp: Footprint, gx: float, gy: float, gtheta: float) -> Tuple[np.ndarray, np.ndarray]:
        return footprint_cells(fp, gx, gy, gtheta, self.res)

    def pose_cost(self, fp: Footprint, gx: float, gy: float, gtheta: float) -> int:
        """Highest cell cost under the footprint at a grid-frame pose; LETHAL when it
        touches an obstacle or leaves the map."""
        rows, cols = self.pose_cells(fp, gx, gy, gtheta)
        h, w = self.shape
        if rows.min() < 0 or cols.min() < 0 or rows.max() >= h or cols.max() >= w:
            return LETHAL
        return int(self.cost[rows, cols].max())

    def collides(self, fp: Footprint, x: float, y: float, theta: float) -> bool:
        """Whether the footprint at a map-frame pose touches an obstacle or leaves the map."""
        gx, gy, gth = self.grid.to_grid_frame(x, y, theta)
        return self.pose_cost(fp, gx, gy, gth) == LETHAL


def slope_grid(grid: OccupancyGrid, height_at) -> np.ndarray:
    """Terrain slope magnitude |grad z| (rise over run) at every cell centre, from a
    height function ``height_at(x, y)`` of map-frame arrays (central differences over
    one cell)."""
    res = grid.resolution
    rows, cols = np.mgrid[0:grid.height, 0:grid.width]
    gx, gy = (cols + 0.5) * res, (rows + 0.5) * res
    h = 0.5 * res

    def z(dx: float, dy: float) -> np.ndarray:
        x, y, _ = grid.to_map_frame(gx + dx, gy + dy)
        return height_at(x, y)

    sx = (z(h, 0.0) - z(-h, 0.0)) / (2 * h)
    sy = (z(0.0, h) - z(0.0, -h)) / (2 * h)
    return np.hypot(sx, sy)


def max_safe_slope(static_stability_factor: float, warn_ratio: float, max_roll: float, warn_fraction: float) -> float:
    """The steepest slope (rise over run) the roll-over monitor accepts without a warning,
    whichever way the vehicle stands on it: a side slope of angle a loads the vehicle
    with ``tan(a)`` g sideways, so ``tan(a) <= warn_ratio * SSF`` and ``a <= warn_fraction * max_roll``."""
    return min(warn_ratio * static_stability_factor, math.tan(warn_fraction * max_roll))
