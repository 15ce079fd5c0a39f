"""Surveyed rasters in the site's frame (quadrivio_terrain.georaster): a synthetic DEM
written with rasterio in a projected CRS reads back to the same heights at the same local
coordinates; the terrain built from it is the simulator's and the planner's; bad rasters
get one clear error."""
import math

import numpy as np
import pytest

import rasterio  # noqa: E402  Debian's python3-rasterio (make setup installs it; no skip)

from quadrivio_config import ConfigError  # noqa: E402
from quadrivio_description.geodesy import LocalFrame  # noqa: E402
from quadrivio_terrain.georaster import (crs_to_local, dem_heightfield, local_to_crs, read_geotiff,  # noqa: E402
                                             resample_to_local)
from quadrivio_terrain.terrain import TerrainParams, build_heightfield  # noqa: E402

FRAME = LocalFrame(45.478070, 9.227690, 165.0)  # the default site (Milan)
UTM33 = "EPSG:32633"  # 5.8 deg east of Milan: grid north 4.1 deg from true north there


def hill(e, n):
    """Heights [m] of the synthetic site: a slope, a hill and a ridge, in local coordinates."""
    return 0.04 * e - 0.02 * n + 6.0 * np.exp(-((e - 30.0) ** 2 + (n + 20.0) ** 2) / 800.0) + \
        1.5 * np.sin(2 * math.pi * (e + 2 * n) / 90.0) + 120.0


def write_dem(path, crs=UTM33, pixel=1.0, half=130.0, nodata=None, hole=None, scale=1.0):
    """A DEM GeoTIFF in ``crs`` covering +-``half`` m about the datum, heights ``hill``."""
    from rasterio.transform import from_origin

    x0, y0 = local_to_crs(FRAME, crs, np.array([0.0]), np.array([0.0]))
    n = int(2 * half / pixel)
    west, north = float(x0[0]) - half, float(y0[0]) + half
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    X, Y = west + cols * pixel, north - rows * pixel
    E, N = crs_to_local(FRAME, crs, X, Y)
    z = (hill(E, N) / scale).astype("float32")
    if hole is not None:
        z[hole] = nodata
    with rasterio.open(path, "w", driver="GTiff", height=n, width=n, count=1, dtype="float32", crs=crs,
                       transform=from_origin(west, north, pixel, pixel), nodata=nodata) as ds:
        ds.write(z, 1)
    return path


def test_the_local_frames_geodesy_agrees_with_proj():
    # the frame's own formulas (one for a fix, the same on arrays for a raster's pixels)
    # against PROJ's geocentric <-> geographic conversion, an implementation not ours (through
    # the module's loader, which points PROJ at Debian's database from inside the venv)
    from quadrivio_terrain.georaster import _libs
    _, pyproj = _libs()

    e, n = np.array([0.0, 250.0, -400.0, 33.3, 5000.0]), np.array([0.0, -120.0, 300.0, 999.0, -7000.0])
    u = np.array([0.0, 3.0, -12.0, 150.0, 40.0])
    lat, lon, h = FRAME.enu_to_lla_arrays(e, n, u)
    x, y, z = FRAME.enu_to_ecef(e, n, u)
    to_geo = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)
    plon, plat, ph = to_geo.transform(x, y, z)
    assert np.allclose(lat, plat, atol=1e-9) and np.allclose(lon, plon, atol=1e-9)
    assert np.allclose(h, ph, atol=1e-3)
    for k in range(len(e)):  # the scalar path is the same formula
        la, lo, alt = FRAME.enu_to_lla(e[k], n[k], u[k])
        assert (la, lo) == pytest.approx((lat[k], lon[k]), abs=1e-12) and alt == pytest.approx(h[k], abs=1e-6)
    back = FRAME.lla_to_enu_arrays(lat, lon, h)
    assert np.allclose(back[0], e, atol=1e-4) and np.allclose(back[1], n, atol=1e-4)
    assert np.allclose(back[2], u, atol=1e-4)


def test_a_utm_dem_reads_back_to_the_same_heights_at_the_same_local_coordinates(tmp_path):
    path = write_dem(str(tmp_path / "dem.tif"))
    hf = dem_heightfield(path, FRAME, 200.0, 1.0, vertical="datum")
    e = np.array([0.0, 80.0, -75.0, 30.0, 95.0, -99.0])
    n = np.array([0.0, 60.0, -90.0, -20.0, -95.0, 99.0])
    assert np.allclose(hf.heights(e, n), hill(e, n) - FRAME.alt0, atol=0.03)
    # relative to the DEM at the origin (the default)
    hf0 = dem_heightfield(path, FRAME, 200.0, 1.0)
    assert np.allclose(hf0.heights(e, n), hill(e, n) - hill(0.0, 0.0), atol=0.03)
    assert hf0.height(0.0, 0.0) == pytest.approx(0.0, abs=0.01)


def test_grid_north_is_not_taken_for_true_north(tmp_path):
    """Read as if the raster's axes were east and north (the affine only, no projection),
    the hill moves by metres: the convergence is 4.1 deg here, 7 m at 100 m."""
    path = write_dem(str(tmp_path / "dem.tif"))
    r = read_geotiff(path)
    x0, y0 = local_to_crs(FRAME, UTM33, np.array([0.0]), np.array([0.0]))
    e, n = np.array([95.0]), np.array([-95.0])
    col, row = r.pixel_of(x0 + e, y0 + n)  # naive: offsets in the CRS taken as east, north
    naive = r.bands[0][int(round(row[0])), int(round(col[0]))]
    assert abs(naive - hill(e, n)[0]) > 0.5
    hf = dem_heightfield(path, FRAME, 200.0, 1.0, vertical="datum")
    assert hf.heights(e, n)[0] == pytest.approx(hill(e, n)[0] - FRAME.alt0, abs=0.03)


def test_the_terrain_kind_geotiff_is_the_simulators_and_the_planners_ground(tmp_path):
    path = write_dem(str(tmp_path / "dem.tif"), crs="EPSG:32632", scale=0.3048)  # in feet
    p = TerrainParams(kind="geotiff", image=path, size=100.0, resolution=0.5, z_scale=0.3048)
    hf = build_heightfield(p, np.random.default_rng(0), FRAME)
    assert hf.shape == (201, 201)
    assert hf.height(30.0, -20.0) == pytest.approx(hill(30.0, -20.0) - hill(0.0, 0.0), abs=0.03)


@pytest.mark.filterwarnings("ignore::rasterio.errors.NotGeoreferencedWarning")
def test_bad_rasters_are_named(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        dem_heightfield(str(tmp_path / "none.tif"), FRAME, 100.0, 1.0)
    # too small for the terrain asked for: says what it covers
    path = write_dem(str(tmp_path / "small.tif"), half=40.0)
    with pytest.raises(ConfigError, match=r"have no height .*covers east -4\d..4\d m"):
        dem_heightfield(path, FRAME, 100.0, 1.0)
    # no-data inside the area
    hole = (slice(100, 110), slice(100, 110))
    path = write_dem(str(tmp_path / "hole.tif"), nodata=-9999.0, hole=hole)
    with pytest.raises(ConfigError, match="no-data"):
        dem_heightfield(path, FRAME, 200.0, 1.0)
    # not georeferenced
    plain = str(tmp_path / "plain.tif")
    with rasterio.open(plain, "w", driver="GTiff", height=10, width=10, count=1, dtype="float32") as ds:
        ds.write(np.zeros((10, 10), "float32"), 1)
    with pytest.raises(ConfigError, match="not georeferenced"):
        read_geotiff(plain)
    # not a raster at all
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"II*\x00 this is not a tiff")
    with pytest.raises(ConfigError, match="cannot read"):
        read_geotiff(str(junk))


def test_a_class_map_resamples_onto_a_north_up_local_grid(tmp_path):
    """Band values by nearest neighbour; cells outside the raster are marked uncovered."""
    from rasterio.transform import from_origin

    x0, y0 = local_to_crs(FRAME, UTM33, np.array([0.0]), np.array([0.0]))
    cls = np.zeros((60, 60), "uint8")
    cls[20:30, 35:45] = 1  # a block east and north of the origin (rows top-down)
    path = str(tmp_path / "classes.tif")
    west, north = float(x0[0]) - 30.0, float(y0[0]) + 30.0
    with rasterio.open(path, "w", driver="GTiff", height=60, width=60, count=1, dtype="uint8", crs=UTM33,
                       transform=from_origin(west, north, 1.0, 1.0)) as ds:
        ds.write(cls, 1)
    r = read_geotiff(path)
    vals, ok, origin = resample_to_local(r, FRAME, 0.5)
    assert ok.mean() > 0.85 and not ok.all()  # the rotated square does not fill its bounding box
    # the block's centre in local coordinates, from its CRS position through PROJ
    be, bn = crs_to_local(FRAME, UTM33, np.array([west + 40.0]), np.array([north - 25.0]))
    row, col = int((bn[0] - origin[1]) / 0.5), int((be[0] - origin[0]) / 0.5)
    assert vals[row, col, 0] == 1
    assert vals[int((-origin[1]) / 0.5), int((-origin[0]) / 0.5), 0] == 0
