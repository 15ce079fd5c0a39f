"""Occupancy maps in the ROS map_server format, read without map_server.

A map is a YAML file next to an image (map_server's format)::

    image: orchard.pgm          # relative to the YAML file, or absolute
    resolution: 0.2             # [m/pixel]
    origin: [-50.0, -50.0, 0.0] # [m, m, rad] pose of the lower-left pixel in the map frame
    occupied_thresh: 0.65       # [1] occupancy probability above which a pixel is occupied
    free_thresh: 0.196          # [1] below which it is free
    negate: 0                   # 1: white is occupied, black free
    mode: trinary               # trinary | scale | raw (optional, default trinary)

Each pixel becomes one cell of an occupancy grid, as map_server computes it. With
``c`` the mean of the pixel's channels in [0, 255] (``255 - c`` when ``negate``)::

    p = (255 - c) / 255
    trinary:  100 if p > occupied_thresh, 0 if p < free_thresh, else -1 (unknown)
    scale:    the same, but in between 1 + 98 (p - free) / (occupied - free); a
              transparent pixel (alpha 0) in between is unknown
    raw:      the value c itself (0..100, 255 = unknown)

Channels: a grey image has one; grey+alpha, RGB and RGBA images are averaged over their
colour channels, and in trinary mode over the alpha channel too (map_server's own
rule, kept so that a map behaves here as it does under map_server). So an aerial or
hillshade image with obstacles painted black works with suitable thresholds.

Loading says what a map holds (occupied, free, unknown fractions: ``OccupancyGrid.summary``)
and warns when it is likely misread (``warnings``: no occupied cell, every cell unknown, or
the image's darkest pixels coming out free, as an RGBA hillshade does in trinary mode with
thresholds of 0.9 / 0.8), naming the mode, thresholds and negate and what the image would
hold read otherwise. ``plan``, the map server, the planner (in every status) and the
simulator say it.

Georeferenced maps (surveys): ``image`` may be a GeoTIFF, placed by its own CRS and
geotransform (no ``origin``; ``resolution`` optional: the grid's, default the raster's), or
a plain image with ``crs: EPSG:32632`` and ``origin`` its lower-left corner in that CRS.
Either is resampled into the map frame about the site's datum (``config/site.yaml``):
:func:`georeferenced`, :mod:`quadrivio_terrain.georaster`.

The grid's row 0 is the image's bottom row (``y`` grows with the row), as in
``nav_msgs/OccupancyGrid``. ROS-free.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Dict, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, load_yaml, param
from quadrivio_runtime.files import atomic_write

UNKNOWN = -1
FREE = 0
OCCUPIED = 100
MODES = ("trinary", "scale", "raw")
MAX_CELLS = 100_000_000  # [1] a map larger than this is refused rather than exhausting memory


class MapError(ConfigError):
    """A map file (YAML or image) is missing, malformed or inconsistent."""


@dataclass(frozen=True)
class MapParams:
    """The map a node loads (map_server, simulator): ``config/map_server.yaml`` and a
    scenario's ``map:`` section."""
    file: str = param("", doc="map_server YAML; relative: to the scenario file's folder (empty: no map)")
    frame_id: str = param("map", doc="frame of the published map")
    occupied: int = param(65, lo=1, hi=100, doc="cells at or above this value are obstacles (simulator)")
    obstacle_height: float = param(1.5, lo=0.05, hi=100.0, unit="m",
                                   doc="simulator: height of the obstacles built from occupied cells")
    tree_size: float = param(1.2, lo=0.0, hi=100.0, unit="m",
                             doc="simulator: occupied blobs no wider than this become cylinders (trees), "
                                 "larger ones boxes")


@dataclass
class OccupancyGrid:
    """Cells of ``resolution`` metres, ``data[row, col]`` in -1 (unknown) or 0..100,
    row 0 at the bottom; ``origin`` is the pose (x, y, yaw) of cell (0, 0)'s outer
    corner in the map frame."""
    data: np.ndarray  # int8, (height, width)
    resolution: float  # [m]
    origin: Tuple[float, float, float] = (0.0, 0.0, 0.0)  # [m, m, rad]
    summary: str = ""  # what the map holds, as load_map read it ("" for a grid made otherwise)
    warnings: Tuple[str, ...] = ()  # what load_map found questionable: an empty map, a misread image

    @property
    def height(self) -> int:
        return int(self.data.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def size(self) -> Tuple[float, float]:
        """Width and height [m]."""
        return self.width * self.resolution, self.height * self.resolution

    def to_grid_frame(self, x: float, y: float, yaw: float = 0.0) -> Tuple[float, float, float]:
        """A map-frame pose in the grid's own frame (origin at cell (0, 0)'s corner, axes
        along the rows and columns)."""
        ox, oy, oyaw = self.origin
        c, s = math.cos(oyaw), math.sin(oyaw)
        dx, dy = x - ox, y - oy
        return c * dx + s * dy, -s * dx + c * dy, yaw - oyaw

    def to_map_frame(self, gx, gy, gyaw=0.0):
        """The inverse of :meth:`to_grid_frame` (scalars or numpy arrays)."""
        ox, oy, oyaw = self.origin
        c, s = math.cos(oyaw), math.sin(oyaw)
        return ox + c * gx - s * gy, oy + s * gx + c * gy, gyaw + oyaw

    def cell_of(self, x: float, y: float) -> Tuple[int, int]:
        """(row, col) of the cell holding map-frame point (x, y); may lie outside the grid."""
        gx, gy, _ = self.to_grid_frame(x, y)
        return int(math.floor(gy / self.resolution)), int(math.floor(gx / self.resolution))

    def contains(self, x: float, y: float) -> bool:
        r, c = self.cell_of(x, y)
        return 0 <= r < self.height and 0 <= c < self.width

    def value_at(self, x: float, y: float) -> Optional[int]:
        """The cell value at map-frame point (x, y), ``None`` outside the grid."""
        r, c = self.cell_of(x, y)
        if 0 <= r < self.height and 0 <= c < self.width:
            return int(self.data[r, c])
        return None

    def blocked(self, unknown: str = "occupied", lethal: int = 65) -> np.ndarray:
        """Boolean mask of the cells a vehicle must not touch: value >= ``lethal``, and
        unknown cells when ``unknown`` is ``occupied``."""
        mask = self.data >= lethal
        if unknown == "occupied":
            mask |= self.data < 0
        return mask


# --------------------------------------------------------------------------- YAML
def _number(data: Dict[str, Any], key: str, source: str, default: Any = None) -> float:
    value = data.get(key, default)
    if value is None:
        raise MapError(f"{source}: '{key}' is missing")
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MapError(f"{source}: '{key}' = {value!r} must be a finite number")
    return float(value)


@dataclass(frozen=True)
class MapMetadata:
    """The YAML half of a map_server map."""
    image: str  # absolute path
    resolution: float  # [m/pixel]
    origin: Tuple[float, float, float]
    occupied_thresh: float
    free_thresh: float
    negate: bool
    mode: str
    path: str = ""  # the YAML file
    crs: str = ""  # the coordinate reference system of ``origin`` and the image ("": the map frame itself)
    geotiff: bool = False  # the image is a georeferenced raster: its own CRS and geotransform place it


MAP_KEYS = ("image", "resolution", "origin", "occupied_thresh", "free_thresh", "negate", "mode", "crs")


def read_metadata(path: str) -> MapMetadata:
    """Read and check a map_server YAML file (not its image)."""
    if not path:
        raise MapError("no map file given (empty path)")
    try:
        data = load_yaml(path)
    except ConfigError as exc:  # file not found, malformed YAML, not a mapping
        raise MapError(f"map {exc}") from exc
    unknown = sorted(set(map(str, data)) - set(MAP_KEYS))
    if unknown:
        raise MapError(f"map {path}: unknown key(s) {', '.join(unknown)}; a map_server YAML has "
                       f"{', '.join(MAP_KEYS)}")
    image = data.get("image")
    if not isinstance(image, str) or not image:
        raise MapError(f"map {path}: 'image' is missing (the PGM or PNG file of the map)")
    image = image if os.path.isabs(image) else os.path.join(os.path.dirname(os.path.abspath(path)), image)
    crs = data.get("crs", "")
    if not isinstance(crs, str):
        raise MapError(f"map {path}: 'crs' = {crs!r} must be a string such as 'EPSG:32632'")
    geotiff = os.path.splitext(image)[1].lower() in (".tif", ".tiff")
    if geotiff:  # placed by its own CRS and geotransform; resolution: the grid's (default the raster's)
        if "origin" in data or crs:
            raise MapError(f"map {path}: the GeoTIFF {os.path.basename(image)} places itself (its own CRS and "
                           f"geotransform): remove 'origin'{' and crs' if crs else ''}")
        resolution = _number(data, "resolution", f"map {path}", 0.0)
        if resolution < 0.0:
            raise MapError(f"map {path}: 'resolution' = {resolution} must be > 0 m/pixel")
        origin = [0.0, 0.0, 0.0]
    else:
        resolution = _number(data, "resolution", f"map {path}")
        if not resolution > 0.0:
            raise MapError(f"map {path}: 'resolution' = {resolution} must be > 0 m/pixel")
        origin = data.get("origin")
        if (not isinstance(origin, (list, tuple)) or len(origin) != 3
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                           for v in origin)):
            raise MapError(f"map {path}: 'origin' = {origin!r} must be [x, y, yaw] (m, m, rad)")
        if crs and origin[2] != 0.0:
            raise MapError(f"map {path}: with a 'crs' the origin's yaw must be 0 (the image's rows run along the "
                           f"CRS's x axis), got {origin[2]}")
    occ = _number(data, "occupied_thresh", f"map {path}")
    free = _number(data, "free_thresh", f"map {path}")
    if not 0.0 <= free <= occ <= 1.0:
        raise MapError(f"map {path}: thresholds must satisfy 0 <= free_thresh ({free}) <= occupied_thresh ({occ}) <= 1")
    negate = data.get("negate", 0)
    if negate not in (0, 1, True, False):
        raise MapError(f"map {path}: 'negate' = {negate!r} must be 0 or 1")
    mode = data.get("mode", "trinary")
    if mode not in MODES:
        raise MapError(f"map {path}: 'mode' = {mode!r} is not one of {', '.join(MODES)}")
    return MapMetadata(image, resolution, (float(origin[0]), float(origin[1]), float(origin[2])), occ, free,
                       bool(negate), mode, path, crs, geotiff)


# -------------------------------------------------------------------------- image
def read_image(path: str) -> Tuple[np.ndarray, bool]:
    """Pixels of a map image as float (height, width, channels) in [0, 255], row 0 the
    image's top, and whether the last channel is alpha."""
    from PIL import Image, UnidentifiedImageError

    if not os.path.isfile(path):
        raise MapError(f"map image {path}: file not found")
    try:
        with Image.open(path) as img:
            img.load()
            if img.width * img.height > MAX_CELLS:
                raise MapError(f"map image {path}: {img.width} x {img.height} pixels is more than the "
                               f"{MAX_CELLS} cells a map may have")
            mode = img.mode
            if mode == "P":  # palette: expand to the colours it stands for
                img = img.convert("RGBA" if "transparency" in img.info else "RGB")
                mode = img.mode
            if mode in ("1", "L"):
                a = np.asarray(img.convert("L"), dtype=float)[..., None]
            elif mode in ("I;16", "I;16B", "I;16L", "I"):  # 16-bit grey: scale to 8 bits
                raw = np.asarray(img, dtype=float)
                a = (raw * (255.0 / 65535.0))[..., None]
            elif mode == "LA":
                a = np.asarray(img, dtype=float)
            elif mode in ("RGB", "RGBA"):
                a = np.asarray(img, dtype=float)
            else:
                a = np.asarray(img.convert("RGB"), dtype=float)
                mode = "RGB"
    except MapError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError) as exc:
        raise MapError(f"map image {path}: cannot read: {exc}") from exc
    if a.ndim != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise MapError(f"map image {path}: empty image")
    return a, mode in ("LA", "RGBA")


def occupancy_from_pixels(pixels: np.ndarray, has_alpha: bool, mode: str, negate: bool, occupied_thresh: float,
                          free_thresh: float, source: str = "image") -> np.ndarray:
    """map_server's pixel rule (module docstring): int8 grid, row 0 = the image's bottom."""
    n = pixels.shape[2]
    colour = pixels if (mode == "trinary" or not has_alpha) else pixels[..., :n - 1]
    avg = colour.mean(axis=2)
    alpha = pixels[..., n - 1] if has_alpha else np.full(avg.shape, 255.0)
    if negate:
        avg = 255.0 - avg
    if mode == "raw":
        value = np.rint(avg).astype(np.int16)
        bad = (value > OCCUPIED) & (value != 255)
        if bad.any():
            raise MapError(f"{source}: raw mode needs pixel values 0..100 or 255 (unknown); "
                           f"{int(bad.sum())} pixels are outside, e.g. {int(value[bad][0])}")
        value[value == 255] = UNKNOWN
        return np.flipud(value.astype(np.int8))
    occ = (255.0 - avg) / 255.0
    out = np.full(avg.shape, UNKNOWN, dtype=np.int16)
    if mode == "scale":
        between = (occ >= free_thresh) & (occ <= occupied_thresh) & (alpha >= 1.0)
        span = max(occupied_thresh - free_thresh, 1e-12)
        out[between] = (1 + 98 * (occ[between] - free_thresh) / span).astype(np.int16)
    out[occ > occupied_thresh] = OCCUPIED
    out[occ < free_thresh] = FREE
    return np.flipud(out.astype(np.int8))


def fractions(data: np.ndarray) -> Tuple[float, float, float]:
    """(occupied, free, unknown) fractions of a grid's cells (occupied: 65 and above)."""
    n = max(1, data.size)
    return (float(np.count_nonzero(data >= 65)) / n, float(np.count_nonzero(data == FREE)) / n,
            float(np.count_nonzero(data == UNKNOWN)) / n)


def _pct(f: float) -> str:
    return f"{100.0 * f:.1f} %" if 0.0 < f < 0.001 or f > 0.999 and f < 1.0 else f"{100.0 * f:.0f} %"


def map_report(meta: "MapMetadata", pixels: np.ndarray, has_alpha: bool, data: np.ndarray) -> Tuple[str, Tuple[str, ...]]:
    """What a map holds (one line), and warnings when it is likely misread: no occupied cell,
    every cell unknown, or the image's darkest pixels (its brightest with negate) coming out
    free; each names the mode, the thresholds, negate, and what the image would give read
    otherwise (the alpha channel left out of the average, negate flipped)."""
    occ, free, unk = fractions(data)
    how = (f"mode {meta.mode}, occupied_thresh {meta.occupied_thresh:g}, free_thresh {meta.free_thresh:g}, "
           f"negate {int(meta.negate)}{', an alpha channel averaged in' if has_alpha and meta.mode == 'trinary' else ''}")
    summary = (f"map {meta.path}: {data.shape[1]} x {data.shape[0]} cells at {meta.resolution:g} m: occupied "
               f"{_pct(occ)}, free {_pct(free)}, unknown {_pct(unk)} ({how})")
    if meta.mode == "raw":
        return summary, ()
    problems = []
    if occ == 0.0:
        problems.append("no cell is occupied")
    if unk >= 0.999:
        problems.append("every cell is unknown")
    n = pixels.shape[2]
    colour = (pixels[..., :n - 1] if has_alpha else pixels).mean(axis=2)
    if meta.negate:
        colour = 255.0 - colour
    darkest = colour <= float(colour.min()) + 2.0
    if colour.max() - colour.min() > 16.0 and np.any(np.flipud(data)[darkest] == FREE):
        problems.append(f"the image's {'brightest' if meta.negate else 'darkest'} pixels come out free")
    if not problems:
        return summary, ()
    others = []
    if has_alpha and meta.mode == "trinary":
        alt = occupancy_from_pixels(pixels, has_alpha, "scale", meta.negate, meta.occupied_thresh, meta.free_thresh)
        o, f, u = fractions(np.where(alt >= 65, OCCUPIED, np.where(alt == FREE, FREE, UNKNOWN)))
        others.append(f"without the alpha channel in the average (mode: scale) occupied {_pct(o)}, free {_pct(f)}")
    alt = occupancy_from_pixels(pixels, has_alpha, meta.mode, not meta.negate, meta.occupied_thresh, meta.free_thresh)
    o, f, u = fractions(alt)
    others.append(f"with negate {int(not meta.negate)} occupied {_pct(o)}, free {_pct(f)}")
    warning = (f"map {meta.path} is likely misread: {' and '.join(problems)} (occupied {_pct(occ)}, free {_pct(free)}, "
               f"unknown {_pct(unk)}; {how}). Read otherwise: {'; '.join(others)}")
    return summary, (warning,)


def grid_warnings(data: np.ndarray, what: str) -> Tuple[str, ...]:
    """For a grid that came without its image (a nav_msgs/OccupancyGrid): no occupied cell,
    or every cell unknown."""
    occ, free, unk = fractions(data)
    problems = (["no cell is occupied"] if occ == 0.0 else []) + (["every cell is unknown"] if unk >= 0.999 else [])
    if not problems:
        return ()
    return (f"{what} is likely misread or empty: {' and '.join(problems)} (occupied {_pct(occ)}, free {_pct(free)}, "
            f"unknown {_pct(unk)}); check the map's mode, thresholds and negate",)


def load_map(path: str, frame=None) -> OccupancyGrid:
    """A map_server map (YAML and image) as an :class:`OccupancyGrid`; :class:`MapError`
    names the file and what is wrong with it. The grid's ``summary`` says what it holds and
    its ``warnings`` what looks misread (callers print or log them: see :func:`map_report`).

    A georeferenced map (a GeoTIFF image, or a YAML with ``crs``) is resampled into the map
    frame about the site's datum (``frame``: a :class:`~quadrivio_description.geodesy.LocalFrame`;
    default: ``config/site.yaml``'s): :func:`georeferenced`."""
    meta = read_metadata(path)
    if meta.geotiff or meta.crs:
        return georeferenced(meta, frame)
    pixels, has_alpha = read_image(meta.image)
    data = occupancy_from_pixels(pixels, has_alpha, meta.mode, meta.negate, meta.occupied_thresh, meta.free_thresh,
                                 f"map image {meta.image}")
    summary, warnings = map_report(meta, pixels, has_alpha, data)
    return OccupancyGrid(np.ascontiguousarray(data), meta.resolution, meta.origin, summary, warnings)


def georeferenced(meta: MapMetadata, frame=None) -> OccupancyGrid:
    """A georeferenced map in the map frame: the image's pixels resampled (nearest
    neighbour) onto a north-up grid about the site's datum at the map's resolution, then
    read by map_server's rule; cells the image does not cover are unknown.

    * a GeoTIFF (``image: site.tif``): its CRS and geotransform place it; ``resolution`` is
      the grid's (default: the raster's pixel size), no ``origin``;
    * a plain image with ``crs: EPSG:...``: ``origin`` is its lower-left corner in that CRS
      and ``resolution`` its pixel size in the CRS's units (metres)."""
    from quadrivio_terrain.georaster import Raster, read_geotiff, resample_to_local, _crs

    if frame is None:
        from quadrivio_description.site import load_site

        frame = load_site().local_frame()
    try:
        if meta.geotiff:
            raster = read_geotiff(meta.image)
            bands = raster.bands
            if bands.max(initial=0.0) > 255.0:  # 16-bit grey, as read_image scales it
                raster.bands = bands * (255.0 / 65535.0)
            has_alpha = bands.shape[0] in (2, 4)
            t = raster.transform
            resolution = meta.resolution or float(math.sqrt(abs(t[1] * t[5] - t[2] * t[4])))
        else:
            pixels, has_alpha = read_image(meta.image)
            h, w = pixels.shape[:2]
            x0, y0, res = meta.origin[0], meta.origin[1], meta.resolution
            raster = Raster(np.moveaxis(pixels, -1, 0), _crs(meta.crs, f"map {meta.path}"),
                            (x0, res, 0.0, y0 + h * res, 0.0, -res), np.ones((h, w), bool), meta.image)
            resolution = res
        vals, covered, origin = resample_to_local(raster, frame, resolution)
    except MapError:
        raise
    except ConfigError as exc:
        raise MapError(f"map {meta.path}: {exc}") from exc
    pixels = np.flipud(vals)  # row 0 the top, as an image
    data = occupancy_from_pixels(pixels, has_alpha, meta.mode, meta.negate, meta.occupied_thresh, meta.free_thresh,
                                 f"map image {meta.image}")
    data[~covered] = UNKNOWN
    placed = MapMetadata(meta.image, resolution, (origin[0], origin[1], 0.0), meta.occupied_thresh, meta.free_thresh,
                         meta.negate, meta.mode, meta.path, meta.crs, meta.geotiff)
    summary, warnings = map_report(placed, pixels, has_alpha, data)
    crs_name = getattr(raster.crs, "name", str(raster.crs))
    summary += (f"; georeferenced ({crs_name}), resampled about the datum {frame.lat0:.6f}, {frame.lon0:.6f}: "
                f"lower-left corner at ({origin[0]:.1f}, {origin[1]:.1f}) m, {100.0 * covered.mean():.0f} % covered")
    return OccupancyGrid(np.ascontiguousarray(data), resolution, (origin[0], origin[1], 0.0), summary, warnings)


def resolve_map_file(file: str, scenario_file: str = "") -> str:
    """A map path from a scenario: absolute as given, relative to the folder the scenario
    file really is in (symbolic links followed: the workspace links to the sources)."""
    if not file or os.path.isabs(file):
        return file
    base = os.path.dirname(os.path.realpath(scenario_file)) if scenario_file else os.getcwd()
    return os.path.normpath(os.path.join(base, file))


# -------------------------------------------------------------------------- write
def save_map(grid: OccupancyGrid, yaml_path: str, image_name: Optional[str] = None) -> str:
    """Write ``grid`` as a trinary map_server map (PGM + YAML); returns the YAML path.

    Both files are written to temporary names and moved into place, so an interrupted
    write leaves no half-written map."""
    import yaml

    image_name = image_name or os.path.splitext(os.path.basename(yaml_path))[0] + ".pgm"
    folder = os.path.dirname(os.path.abspath(yaml_path))
    os.makedirs(folder, exist_ok=True)
    pix = np.full(grid.data.shape, 205, dtype=np.uint8)  # map_saver's grey for unknown
    pix[grid.data == FREE] = 254
    pix[grid.data >= 65] = 0
    pix[(grid.data > FREE) & (grid.data < 65)] = 205
    pix = np.flipud(pix)
    image_path = os.path.join(folder, image_name)
    header = f"P5\n{grid.width} {grid.height}\n255\n".encode("ascii")
    atomic_write(image_path, header + pix.tobytes())
    meta = {"image": image_name, "resolution": float(grid.resolution), "origin": [float(v) for v in grid.origin],
            "negate": 0, "occupied_thresh": 0.65, "free_thresh": 0.196, "mode": "trinary"}
    atomic_write(yaml_path, yaml.safe_dump(meta, sort_keys=False).encode("utf-8"))
    return yaml_path


# ---------------------------------------------------------------- obstacles (sim)
@dataclass(frozen=True)
class Block:
    """A static obstacle made from occupied cells, in the map frame."""
    kind: str  # "box" or "cylinder"
    x: float  # [m] centre
    y: float
    size_x: float  # [m] box: length along the grid's x; cylinder: diameter
    size_y: float  # [m] box: width along the grid's y; cylinder: diameter
    yaw: float  # [rad] the grid's rotation


def obstacles_from_grid(grid: OccupancyGrid, occupied: int = 65, tree_size: float = 1.2) -> list:
    """Static obstacles covering every cell at or above ``occupied``: each 8-connected
    blob no wider than ``tree_size`` becomes one cylinder (a tree or a post) around it,
    every other blob a few boxes (runs of cells in a row, merged with identical runs in
    the rows above), so that a wall or a building is a handful of boxes, not thousands
    of cells. Boxes cover exactly the blob's cells."""
    from scipy import ndimage

    occ = grid.data >= occupied
    labels, n = ndimage.label(occ, structure=np.ones((3, 3), dtype=bool))
    if n == 0:
        return []
    res = grid.resolution
    yaw = grid.origin[2]
    out = []
    for k, sl in enumerate(ndimage.find_objects(labels), start=1):
        rows, cols = sl
        h, w = rows.stop - rows.start, cols.stop - cols.start
        mask = labels[sl] == k
        if max(h, w) * res <= tree_size:
            rr, cc = np.nonzero(mask)
            cx = (cols.start + cc.mean() + 0.5) * res
            cy = (rows.start + rr.mean() + 0.5) * res
            # radius reaching the farthest cell corner from the centroid
            d = np.hypot((cols.start + cc + 0.5) * res - cx, (rows.start + rr + 0.5) * res - cy) + 0.5 * res * math.sqrt(2)
            r = float(d.max())
            x, y, _ = grid.to_map_frame(cx, cy)
            out.append(Block("cylinder", float(x), float(y), 2 * r, 2 * r, yaw))
            continue
        for r0, r1, c0, c1 in _rectangles(mask):
            gx = (cols.start + 0.5 * (c0 + c1)) * res
            gy = (rows.start + 0.5 * (r0 + r1)) * res
            x, y, _ = grid.to_map_frame(gx, gy)
            out.append(Block("box", float(x), float(y), (c1 - c0) * res, (r1 - r0) * res, yaw))
    return out


def _rectangles(mask: np.ndarray):
    """Cover a boolean mask by rectangles ``(r0, r1, c0, c1)`` (half-open): runs of
    True cells in each row, extended upwards while the next row has the same run."""
    open_runs = {}  # (c0, c1) -> r0
    out = []
    h = mask.shape[0]
    for r in range(h + 1):
        runs = set()
        if r < h:
            row = np.concatenate([[False], mask[r], [False]])
            edges = np.flatnonzero(row[1:] != row[:-1])
            runs = {(int(a), int(b)) for a, b in zip(edges[0::2], edges[1::2])}
        for run in list(open_runs):
            if run not in runs:
                out.append((open_runs.pop(run), r, run[0], run[1]))
        for run in runs:
            open_runs.setdefault(run, r)
    return out
