"""The site's terrain: flat ground, a DEM image, a surveyed DEM GeoTIFF, or a procedural rough surface.

Shared by the simulator (a PyBullet heightfield) and the planner (slope cost and slopes
too steep to drive), so both see the same ground. A terrain is a regular grid of heights
``z[i, j]`` at ``x = x0 + j * res`` and ``y = y0 + i * res`` (row ``i`` northwards,
column ``j`` eastwards), centred on the world origin (a GeoTIFF DEM is resampled onto
such a grid in the site's local frame: :mod:`quadrivio_terrain.georaster`); :meth:`Heightfield.height` gives
the bilinear height anywhere (spawning, tests), :meth:`Heightfield.heights` for arrays.
The procedural surface is drawn from the generator it is given: the simulator passes
``numpy.random.default_rng(seed)`` before any other draw, so
``build_heightfield(p, default_rng(seed))`` rebuilds the simulated ground elsewhere.

Procedural terrain (seeded)::

    z(x, y) = g_x x + g_y y + sum_k a_k sin(2 pi (u_k . (x, y)) / lambda_k + phi_k)

a sum of ``waves`` sinusoids with random directions ``u_k``, wavelengths around
``wavelength`` and phases, scaled so that the RMS of the rough part is ``roughness``;
``g_x``, ``g_y`` is a constant slope.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, param


@dataclass(frozen=True)
class TerrainParams:
    kind: str = param("flat", choices=("flat", "image", "geotiff", "procedural"),
                      doc="flat plane, heightfield from a DEM image, a georeferenced DEM (GeoTIFF) in the site's "
                          "frame, or procedural rough ground")
    image: str = param("", doc="DEM image (PNG greyscale, PGM, or .npy of heights in m) for kind=image; the DEM "
                               "GeoTIFF (any CRS) for kind=geotiff, sampled over size x size m about the site's datum")
    vertical: str = param("origin", choices=("origin", "datum"),
                          doc="kind=geotiff: heights relative to the DEM at the map origin, or to the datum's "
                              "altitude (a DEM of ellipsoidal heights)")
    z_scale: float = param(1.0, lo=1e-6, hi=1e6, unit="m",
                           doc="kind=geotiff: metres per DEM unit (0.3048 for a DEM in feet)")
    size: float = param(200.0, lo=10.0, hi=5000.0, unit="m", doc="side of the square terrain patch")
    resolution: float = param(0.5, lo=0.05, hi=10.0, unit="m", doc="grid spacing")
    height_range: float = param(2.0, lo=0.0, hi=500.0, unit="m",
                                doc="height of white above black in a DEM image")
    roughness: float = param(0.05, lo=0.0, hi=5.0, unit="m", doc="RMS height of procedural bumps")
    wavelength: float = param(4.0, lo=0.2, hi=500.0, unit="m", doc="typical bump wavelength")
    waves: int = param(24, lo=1, hi=500, doc="number of sinusoids in the procedural surface")
    slope: Tuple[float, float] = param((0.0, 0.0), lo=-2.0, hi=2.0, unit="1",
                                       doc="constant slope dz/dx, dz/dy of procedural terrain")
    flat_radius: float = param(3.0, lo=0.0, hi=100.0, unit="m",
                               doc="procedural terrain is blended to flat within this radius of the origin")
    friction: float = param(0.8, lo=0.0, hi=3.0, unit="1", doc="ground friction coefficient (combined with the tyre's by product)")
    rolling_resistance: float = param(0.03, lo=0.0, hi=1.0, unit="1",
                                      doc="rolling resistance coefficient Crr: force = Crr x wheel load")


class Heightfield:
    """Heights ``z`` [m] on a grid of spacing ``res`` [m] centred on the origin."""

    def __init__(self, z: np.ndarray, res: float) -> None:
        if z.ndim != 2 or min(z.shape) < 2:
            raise ConfigError(f"terrain heights must be a 2-D grid of at least 2 x 2, got shape {z.shape}")
        if not np.all(np.isfinite(z)):
            raise ConfigError("terrain heights contain NaN or infinite values")
        self.z = np.ascontiguousarray(z, dtype=float)
        self.res = float(res)
        rows, cols = self.z.shape
        self.x0 = -0.5 * (cols - 1) * res
        self.y0 = -0.5 * (rows - 1) * res
        # level ground at z = 0 (known_heightfield's flat site): every finite point's height
        # is 0, as the bilinear sum of zeros gives, without the arithmetic (the ground tests
        # of the guard and the layer ask for thousands of points a scan: an orchard run's CPU
        # 21.0 -> 14.0 s)
        self.level = not np.any(self.z)

    @property
    def shape(self) -> Tuple[int, int]:
        return self.z.shape  # type: ignore[return-value]

    def height(self, x: float, y: float) -> float:
        """Bilinear height at ``(x, y)`` [m]; outside the grid the edge value."""
        if self.level and math.isfinite(x) and math.isfinite(y):
            return 0.0
        rows, cols = self.z.shape
        fx = min(max((x - self.x0) / self.res, 0.0), cols - 1.000001)
        fy = min(max((y - self.y0) / self.res, 0.0), rows - 1.000001)
        j, i = int(fx), int(fy)
        tx, ty = fx - j, fy - i
        z = self.z
        return float((1 - ty) * ((1 - tx) * z[i, j] + tx * z[i, j + 1]) + ty * ((1 - tx) * z[i + 1, j] + tx * z[i + 1, j + 1]))

    def heights(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear heights at arrays of points (:meth:`height` for many points)."""
        if self.level and np.isfinite(x).all() and np.isfinite(y).all():
            return np.zeros(np.broadcast(x, y).shape)
        if np.ndim(x) == 1 and len(x) <= 4 and all(map(math.isfinite, x)) and all(map(math.isfinite, y)):
            # the guard's and the layer's few points: numpy's overhead was most of their cost
            return np.array([self.height(a, b) for a, b in zip(x, y)])
        rows, cols = self.z.shape
        # not np.clip: 8 times slower on a few points (the guard's and the layer's calls)
        fx = np.minimum(np.maximum((np.asarray(x, float) - self.x0) / self.res, 0.0), cols - 1.000001)
        fy = np.minimum(np.maximum((np.asarray(y, float) - self.y0) / self.res, 0.0), rows - 1.000001)
        j, i = fx.astype(int), fy.astype(int)
        tx, ty = fx - j, fy - i
        z = self.z
        return (1 - ty) * ((1 - tx) * z[i, j] + tx * z[i, j + 1]) + ty * ((1 - tx) * z[i + 1, j] + tx * z[i + 1, j + 1])

    def gradient(self, x: float, y: float) -> Tuple[float, float]:
        """Central-difference slope ``(dz/dx, dz/dy)`` at ``(x, y)``."""
        h = 0.5 * self.res
        return ((self.height(x + h, y) - self.height(x - h, y)) / (2 * h),
                (self.height(x, y + h) - self.height(x, y - h)) / (2 * h))


def read_dem(path: str) -> np.ndarray:
    """Read a DEM image as a float array in [0, 1] (image files) or metres (``.npy``).

    Row 0 of an image is its top edge (north); the returned array has row 0 south so
    that row index grows with y.
    """
    if not path:
        raise ConfigError("terrain.kind is 'image' but terrain.image is empty")
    if not os.path.isfile(path):
        raise ConfigError(f"terrain image {path}: file not found")
    ext = os.path.splitext(path)[1].lower()
    try:
        if ext == ".npy":
            return np.asarray(np.load(path), dtype=float)
        if ext in (".pgm", ".pnm"):
            data = _read_pgm(path)
        else:
            import matplotlib.image as mpimg

            data = np.asarray(mpimg.imread(path), dtype=float)
    except (OSError, ValueError, SyntaxError) as exc:
        raise ConfigError(f"terrain image {path}: cannot read: {exc}") from exc
    if data.ndim == 3:  # RGB(A): luminance
        data = data[..., :3].mean(axis=2)
    if data.ndim != 2:
        raise ConfigError(f"terrain image {path}: expected a greyscale image, got shape {data.shape}")
    if data.max() > 1.0:
        data = data / (65535.0 if data.max() > 255.0 else 255.0)
    return np.flipud(data)


def _read_pgm(path: str) -> np.ndarray:
    with open(path, "rb") as fh:
        raw = fh.read()
    tokens = []
    pos = 0
    while len(tokens) < 4:
        while raw[pos:pos + 1].isspace():
            pos += 1
        if raw[pos:pos + 1] == b"#":
            pos = raw.index(b"\n", pos)
            continue
        start = pos
        while not raw[pos:pos + 1].isspace():
            pos += 1
        tokens.append(raw[start:pos])
    magic, w, h, maxval = tokens[0], int(tokens[1]), int(tokens[2]), int(tokens[3])
    if magic != b"P5":
        raise ValueError(f"only binary PGM (P5) is supported, got {magic!r}")
    dtype = ">u2" if maxval > 255 else "u1"
    data = np.frombuffer(raw, dtype=dtype, count=w * h, offset=pos + 1).reshape(h, w)
    return data.astype(float) / maxval


def known_heightfield(p: TerrainParams, rng: np.random.Generator, frame=None) -> Heightfield:
    """The terrain as the stack knows it (the guard's and the obstacle layer's DEM, the
    planner's slopes): :func:`build_heightfield`'s, and for flat ground a level grid at
    z = 0, known as well: a vehicle braking hard pitches its scanners' plane into it (4 deg
    at 1.5 m/s puts the ground 8 m ahead in a scan), and those returns are the ground."""
    if p.kind == "flat":
        return Heightfield(np.zeros((2, 2)), max(p.size, 1.0))
    return build_heightfield(p, rng, frame)


def build_heightfield(p: TerrainParams, rng: np.random.Generator, frame=None) -> Optional[Heightfield]:
    """The heightfield for ``p``; ``None`` for flat ground. ``frame``: the site's
    :class:`~quadrivio_description.geodesy.LocalFrame` for kind=geotiff (default: the
    datum of ``config/site.yaml``)."""
    if p.kind == "flat":
        return None
    if p.kind == "geotiff":
        from .georaster import dem_heightfield

        if frame is None:
            from quadrivio_description.site import load_site

            frame = load_site().local_frame()
        return dem_heightfield(p.image, frame, p.size, p.resolution, p.vertical, p.z_scale)
    if p.kind == "image":
        dem = read_dem(p.image)
        if p.image.endswith(".npy"):
            return Heightfield(dem, p.resolution)
        return Heightfield(dem * p.height_range, p.resolution)
    n = int(round(p.size / p.resolution)) + 1
    coords = (np.arange(n) - 0.5 * (n - 1)) * p.resolution
    X, Y = np.meshgrid(coords, coords)
    rough = np.zeros_like(X)
    for _ in range(p.waves):
        ang = rng.uniform(0.0, 2.0 * math.pi)
        lam = p.wavelength * rng.uniform(0.5, 2.0)
        phase = rng.uniform(0.0, 2.0 * math.pi)
        rough += math.sqrt(lam / p.wavelength) * np.sin(2.0 * math.pi * (X * math.cos(ang) + Y * math.sin(ang)) / lam + phase)
    std = float(rough.std())
    if std > 0.0:
        rough *= p.roughness / std
    r = np.hypot(X, Y)
    blend = np.clip((r - p.flat_radius) / max(p.flat_radius, 1e-6), 0.0, 1.0) if p.flat_radius > 0 else 1.0
    z = p.slope[0] * X + p.slope[1] * Y + rough * blend
    return Heightfield(z, p.resolution)
