"""Surveyed rasters in the site's local frame: a DEM GeoTIFF as terrain, a georeferenced map.

Field teams survey their sites with drones and get GeoTIFFs in a projected coordinate
reference system (UTM, a national grid): a DEM (elevations) and an orthophoto or a
classified map. The stack works in the map frame, East-North-Up about the site's datum
(``config/site.yaml``, :class:`quadrivio_description.geodesy.LocalFrame`). This module
resamples such a raster onto a regular grid of that frame:

    local (east, north) --LocalFrame--> WGS-84 lon/lat --pyproj--> the raster's CRS (x, y)
    --the raster's affine transform, inverted--> (column, row) --bilinear or nearest--> value

Every cell of the local grid is sampled where it really lies, so a grid's north is true
north, not the projection's grid north (in UTM they differ by the meridian convergence,
about 1.4 deg at 45 deg N, 3 deg from the central meridian: 16 m across 650 m).

* :func:`dem_heightfield`: a DEM as the terrain (:class:`Heightfield`, centred on the
  origin), for the simulator (``sim.terrain.kind: geotiff``) and the planner's slope cost.
  Heights are relative to the DEM at the map origin (``vertical: origin``) or to the
  datum's altitude (``vertical: datum``, for a DEM of heights above the ellipsoid).
* :func:`resample_to_local`: any raster's bands onto a local grid (nearest neighbour, for
  class maps and images), with a mask of the cells it does not cover; the map loader
  (``quadrivio_navigation.maps``) uses it for GeoTIFF maps and for map_server maps whose
  YAML names a ``crs``.

Bad input gets a :class:`~quadrivio_config.ConfigError` naming the file and the
problem: no georeferencing, a CRS PROJ does not know, an area the raster does not cover,
no-data cells in the area. GDAL's readers (rasterio) and PROJ (pyproj) come from Debian
(``python3-rasterio``, ``python3-pyproj``); PROJ's database is looked up in
``/usr/share/proj`` when the virtual environment's prefix has none.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError
from quadrivio_description.geodesy import LocalFrame


def _proj_data() -> None:
    """pyproj looks for PROJ's database under ``sys.prefix`` (the venv's, which has none)."""
    if not os.environ.get("PROJ_DATA") and not os.environ.get("PROJ_LIB"):
        for folder in ("/usr/share/proj", "/usr/local/share/proj"):
            if os.path.isfile(os.path.join(folder, "proj.db")):
                os.environ["PROJ_DATA"] = folder
                break


def _libs():
    _proj_data()
    try:
        import pyproj
        import rasterio
    except ImportError as exc:  # pragma: no cover - make setup installs both
        raise ConfigError(f"reading GeoTIFFs needs rasterio and pyproj (Debian: python3-rasterio, python3-pyproj; "
                          f"make setup installs them): {exc}") from exc
    return rasterio, pyproj


# ------------------------------------------------------------------ local <-> lon/lat
def _crs(value, source: str):
    _, pyproj = _libs()
    try:
        return pyproj.CRS.from_user_input(value)
    except Exception as exc:  # pyproj.exceptions.CRSError and PROJ's own
        raise ConfigError(f"{source}: coordinate reference system {value!r} is not known to PROJ: {exc}") from exc


def local_to_crs(frame: LocalFrame, crs, e, n, source: str = "raster") -> Tuple[np.ndarray, np.ndarray]:
    """Local (east, north) [m] to coordinates (x, y) of ``crs`` (anything pyproj takes)."""
    _, pyproj = _libs()
    crs = _crs(crs, source)
    lat, lon, _ = frame.enu_to_lla_arrays(e, n, 0.0)
    tr = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    x, y = tr.transform(lon, lat)
    return np.asarray(x, float), np.asarray(y, float)


def crs_to_local(frame: LocalFrame, crs, x, y, source: str = "raster") -> Tuple[np.ndarray, np.ndarray]:
    """Coordinates (x, y) of ``crs`` to local (east, north) [m] (heights at the datum)."""
    _, pyproj = _libs()
    crs = _crs(crs, source)
    tr = pyproj.Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = tr.transform(np.asarray(x, float), np.asarray(y, float))
    e, n, _ = frame.lla_to_enu_arrays(lat, lon, frame.alt0)
    return e, n


# ------------------------------------------------------------------------- rasters
@dataclass
class Raster:
    """A raster's bands (bands, rows, cols; row 0 the top), where they lie and what is no data."""
    bands: np.ndarray
    crs: object  # pyproj.CRS
    transform: Tuple[float, float, float, float, float, float]  # GDAL order: x0, dx/dcol, dx/drow, y0, dy/dcol, dy/drow
    valid: np.ndarray  # (rows, cols) bool: a value, not no-data
    path: str = ""

    def pixel_of(self, x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Fractional (column, row) of CRS points, pixel centres at integers."""
        x0, a, b, y0, d, e = self.transform
        det = a * e - b * d
        if det == 0.0:
            raise ConfigError(f"{self.path}: the raster's geotransform is singular")
        dx, dy = np.asarray(x) - x0, np.asarray(y) - y0
        col = (e * dx - b * dy) / det
        row = (-d * dx + a * dy) / det
        return col - 0.5, row - 0.5


def read_geotiff(path: str) -> Raster:
    """A GeoTIFF (any raster GDAL reads with a CRS and a geotransform) as a :class:`Raster`."""
    rasterio, _ = _libs()
    if not path or not os.path.isfile(path):
        raise ConfigError(f"raster {path!r}: file not found")
    import warnings

    try:
        with warnings.catch_warnings():  # GDAL's NotGeoreferencedWarning: said below as an error
            warnings.simplefilter("ignore")
            ds = rasterio.open(path)
        with ds:
            if ds.crs is None:
                raise ConfigError(f"raster {path}: no coordinate reference system (not georeferenced); a plain "
                                  f"image is read as a map_server map (YAML with resolution and origin) instead")
            t = ds.transform
            if t.is_identity:
                raise ConfigError(f"raster {path}: no geotransform (pixel size and position) in the file")
            bands = ds.read().astype(float)
            masks = ds.read_masks()  # 0: no data (nodata value, alpha or internal mask)
            crs = _crs(ds.crs.to_wkt(), f"raster {path}")
    except ConfigError:
        raise
    except Exception as exc:  # rasterio.errors.RasterioIOError and GDAL's own
        raise ConfigError(f"raster {path}: cannot read: {exc}") from exc
    valid = np.all(masks > 0, axis=0) & np.all(np.isfinite(bands), axis=0)
    return Raster(bands, crs, (t.c, t.a, t.b, t.f, t.d, t.e), valid, path)


def _grid(size: Tuple[float, float], resolution: float, centre: Tuple[float, float] = (0.0, 0.0)):
    cols = int(round(size[0] / resolution)) + 1
    rows = int(round(size[1] / resolution)) + 1
    e = centre[0] + (np.arange(cols) - 0.5 * (cols - 1)) * resolution
    n = centre[1] + (np.arange(rows) - 0.5 * (rows - 1)) * resolution
    return np.meshgrid(e, n)


def sample(raster: Raster, frame: LocalFrame, e: np.ndarray, n: np.ndarray, method: str = "bilinear",
           band: Optional[int] = 0) -> Tuple[np.ndarray, np.ndarray]:
    """The raster's values at local points, and where they are defined (inside the raster,
    every pixel used holding data). ``band`` None: every band (last axis)."""
    x, y = local_to_crs(frame, raster.crs, e, n, f"raster {raster.path}")
    col, row = raster.pixel_of(x, y)
    rows, cols = raster.valid.shape
    data = raster.bands if band is None else raster.bands[band:band + 1]
    if method == "nearest":
        c, r = np.rint(col).astype(int), np.rint(row).astype(int)
        inside = (c >= 0) & (c < cols) & (r >= 0) & (r < rows)
        cc, rr = np.clip(c, 0, cols - 1), np.clip(r, 0, rows - 1)
        ok = inside & raster.valid[rr, cc]
        vals = np.moveaxis(data[:, rr, cc], 0, -1)
    else:
        inside = (col >= -0.5) & (col <= cols - 0.5) & (row >= -0.5) & (row <= rows - 0.5)
        cf, rf = np.clip(col, 0.0, cols - 1.000001), np.clip(row, 0.0, rows - 1.000001)
        c0, r0 = cf.astype(int), rf.astype(int)
        tc, tr = cf - c0, rf - r0
        c1, r1 = np.minimum(c0 + 1, cols - 1), np.minimum(r0 + 1, rows - 1)
        ok = inside & raster.valid[r0, c0] & raster.valid[r0, c1] & raster.valid[r1, c0] & raster.valid[r1, c1]
        v = data
        vals = ((1 - tr) * ((1 - tc) * v[:, r0, c0] + tc * v[:, r0, c1]) + tr * ((1 - tc) * v[:, r1, c0] + tc * v[:, r1, c1]))
        vals = np.moveaxis(vals, 0, -1)
    return (vals[..., 0] if band is not None else vals), ok


def dem_heightfield(path: str, frame: LocalFrame, size: float, resolution: float, vertical: str = "origin",
                    z_scale: float = 1.0):
    """The DEM GeoTIFF at ``path`` as a :class:`~quadrivio_terrain.terrain.Heightfield`
    of ``size`` x ``size`` m at ``resolution`` about the map origin. ``vertical``: heights
    relative to the DEM at the origin (``origin``) or to the datum's altitude (``datum``);
    ``z_scale``: the DEM's vertical unit in metres (0.3048 for feet)."""
    from .terrain import Heightfield

    raster = read_geotiff(path)
    E, N = _grid((size, size), resolution)
    z, ok = sample(raster, frame, E, N, "bilinear")
    if not ok.all():
        bad = ~ok
        where = f"e.g. at ({E[bad][0]:.1f}, {N[bad][0]:.1f}) m"
        outside = _covered_extent(raster, frame)
        raise ConfigError(f"DEM {path}: {int(bad.sum())} of {bad.size} cells of the {size:g} m terrain about the "
                          f"map origin have no height ({where}; outside the raster or no-data); the raster covers "
                          f"{outside} in the map frame: reduce terrain.size or move the site's datum")
    z = z * z_scale
    if vertical == "origin":
        z0, ok0 = sample(raster, frame, np.array([0.0]), np.array([0.0]), "bilinear")
        z = z - float(z0[0]) * z_scale
    elif vertical == "datum":
        z = z - frame.alt0
    else:
        raise ConfigError(f"DEM {path}: vertical {vertical!r} is not 'origin' or 'datum'")
    return Heightfield(z, resolution)


def _covered_extent(raster: Raster, frame: LocalFrame) -> str:
    rows, cols = raster.valid.shape
    x0, a, b, y0, d, e = raster.transform
    cx = np.array([0, cols, 0, cols], float)
    cy = np.array([0, 0, rows, rows], float)
    xs, ys = x0 + a * cx + b * cy, y0 + d * cx + e * cy
    try:
        E, N = crs_to_local(frame, raster.crs, xs, ys, f"raster {raster.path}")
    except ConfigError:
        return "an area PROJ cannot place"
    return f"east {E.min():.0f}..{E.max():.0f} m, north {N.min():.0f}..{N.max():.0f} m"


def resample_to_local(raster: Raster, frame: LocalFrame, resolution: float,
                      extent: Optional[Tuple[float, float, float, float]] = None):
    """Every band of ``raster`` on a north-up local grid of ``resolution`` (nearest
    neighbour): ``(values (rows, cols, bands) with row 0 south, covered (rows, cols),
    origin (east, north) of cell (0, 0)'s outer corner)``. ``extent`` (e_min, n_min, e_max,
    n_max) [m]; default: the raster's footprint in the map frame."""
    if extent is None:
        rows, cols = raster.valid.shape
        x0, a, b, y0, d, e = raster.transform
        cx = np.array([0, cols, 0, cols], float)
        cy = np.array([0, 0, rows, rows], float)
        E, N = crs_to_local(frame, raster.crs, x0 + a * cx + b * cy, y0 + d * cx + e * cy, f"raster {raster.path}")
        extent = (float(E.min()), float(N.min()), float(E.max()), float(N.max()))
    e0, n0, e1, n1 = extent
    cols = max(1, int(math.ceil((e1 - e0) / resolution - 1e-6)))
    rows = max(1, int(math.ceil((n1 - n0) / resolution - 1e-6)))
    if rows * cols > 100_000_000:
        raise ConfigError(f"raster {raster.path}: {cols} x {rows} cells at {resolution:g} m is too large a grid")
    ec = e0 + (np.arange(cols) + 0.5) * resolution
    nc = n0 + (np.arange(rows) + 0.5) * resolution
    E, N = np.meshgrid(ec, nc)
    vals, ok = sample(raster, frame, E, N, "nearest", band=None)
    return vals, ok, (e0, n0)
