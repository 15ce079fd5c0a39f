"""Maps drawn from a few parameters and a seed: an orchard, a field with scattered
obstacles. They make the scenarios' maps (``tools/make_maps.py`` writes
``scenarios/maps/``), the planner benchmark's maps and the tests' maps. ROS-free."""

from __future__ import annotations

import math
from typing import Tuple

import numpy as np

from .maps import FREE, OCCUPIED, OccupancyGrid


class Canvas:
    """An occupancy grid being drawn in map coordinates (origin yaw 0)."""

    def __init__(self, x0: float, y0: float, width: float, height: float, res: float) -> None:
        self.res = res
        self.origin = (x0, y0, 0.0)
        self.data = np.full((int(round(height / res)), int(round(width / res))), FREE, dtype=np.int8)
        rows, cols = self.data.shape
        self.X = x0 + (np.arange(cols) + 0.5) * res
        self.Y = y0 + (np.arange(rows) + 0.5) * res

    def disc(self, x: float, y: float, r: float) -> None:
        c0, c1 = np.searchsorted(self.X, [x - r - self.res, x + r + self.res])
        r0, r1 = np.searchsorted(self.Y, [y - r - self.res, y + r + self.res])
        xx, yy = np.meshgrid(self.X[c0:c1], self.Y[r0:r1])
        self.data[r0:r1, c0:c1][(xx - x) ** 2 + (yy - y) ** 2 <= r * r] = OCCUPIED

    def box(self, x: float, y: float, sx: float, sy: float, yaw: float = 0.0) -> None:
        half = 0.5 * math.hypot(sx, sy) + self.res
        c0, c1 = np.searchsorted(self.X, [x - half, x + half])
        r0, r1 = np.searchsorted(self.Y, [y - half, y + half])
        xx, yy = np.meshgrid(self.X[c0:c1] - x, self.Y[r0:r1] - y)
        c, s = math.cos(yaw), math.sin(yaw)
        inside = (np.abs(c * xx + s * yy) <= 0.5 * sx) & (np.abs(-s * xx + c * yy) <= 0.5 * sy)
        self.data[r0:r1, c0:c1][inside] = OCCUPIED

    def border(self, thickness: float) -> None:
        k = max(1, int(round(thickness / self.res)))
        self.data[:k, :] = self.data[-k:, :] = OCCUPIED
        self.data[:, :k] = self.data[:, -k:] = OCCUPIED

    def grid(self) -> OccupancyGrid:
        return OccupancyGrid(self.data.copy(), self.res, self.origin)


def orchard(rows: int = 6, row_spacing: float = 5.0, row_length: float = 39.0, tree_spacing: float = 1.5,
            tree_radius: float = 0.45, headland: Tuple[float, float] = (10.0, 9.0), res: float = 0.2,
            seed: int = 0, missing: float = 0.0) -> OccupancyGrid:
    """Rows of trees along x, the first at y = 0 starting at x = 0, with a headland of
    ``headland`` metres before and after the rows and a fence around; trees jittered a
    little (seeded), a fraction ``missing`` of them left out."""
    rng = np.random.default_rng(seed)
    margin = 6.0
    x0, x1 = -headland[0], row_length + headland[1]
    y0, y1 = -margin, (rows - 1) * row_spacing + margin
    cv = Canvas(x0, y0, x1 - x0, y1 - y0, res)
    for i in range(rows):
        y = i * row_spacing
        for x in np.arange(0.0, row_length + 1e-9, tree_spacing):
            if rng.random() < missing:
                continue  # a missing tree
            cv.disc(x + rng.normal(0, 0.1), y + rng.normal(0, 0.1), tree_radius * rng.uniform(0.85, 1.15))
    cv.border(0.4)
    return cv.grid()


def scattered(size: float = 100.0, res: float = 0.2, seed: int = 0, rocks: int = 60, buildings: int = 8,
              clear: Tuple[Tuple[float, float, float], ...] = ()) -> OccupancyGrid:
    """A square field centred on the origin with scattered round obstacles (trees, rocks,
    bushes, 0.5-3 m radius) and rectangular buildings (3-14 m), a fence around, and the
    discs ``clear`` (x, y, radius) kept free (start and goal areas). Seeded."""
    rng = np.random.default_rng(seed)
    h = 0.5 * size
    cv = Canvas(-h, -h, size, size, res)
    for _ in range(rocks):
        cv.disc(rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(0.5, 3.0))
    for _ in range(buildings):
        cv.box(rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(3.0, 14.0), rng.uniform(3.0, 10.0),
               rng.uniform(0.0, math.pi))
    for x, y, r in clear:
        xx, yy = np.meshgrid(cv.X, cv.Y)
        cv.data[(xx - x) ** 2 + (yy - y) ** 2 <= r * r] = FREE
    cv.border(0.4)
    return cv.grid()


def yard(res: float = 0.2) -> OccupancyGrid:
    """A 40 m x 26 m walled yard with a blind alley 2.6 m wide and 16 m deep (too narrow to
    turn in: leaving it facing its end takes reversing) and a closed pen (a goal inside it
    is unreachable). The alley runs along y = 0 from x = 0 to 16, the pen is at x = -14..-8,
    y = 5..11."""
    cv = Canvas(-22.0, -13.0, 40.0, 26.0, res)
    cv.box(8.0, 1.5, 16.0, 0.4)
    cv.box(8.0, -1.5, 16.0, 0.4)
    cv.box(16.2, 0.0, 0.4, 3.4)  # the alley's end
    cv.box(9.0, 7.5, 18.0, 11.0)  # solid ground around the alley
    cv.box(9.0, -7.5, 18.0, 11.0)
    for x, y, sx, sy in ((-11.0, 5.0, 6.4, 0.4), (-11.0, 11.0, 6.4, 0.4), (-14.0, 8.0, 0.4, 6.4),
                         (-8.0, 8.0, 0.4, 6.4)):
        cv.box(x, y, sx, sy)  # the pen
    cv.border(0.4)
    return cv.grid()
