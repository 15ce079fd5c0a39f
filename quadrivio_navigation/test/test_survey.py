"""A surveyed site (issue 27, item 6): a DEM GeoTIFF in UTM and a map in the same CRS give
a simulated world and a plan that agree. The map's buildings, as the simulator builds them
(``obstacles_from_grid``), stay clear of the planned path's footprint; the DEM, as the
simulator's ground (``terrain.kind: geotiff``), is never driven where steeper than the
planner's limit; a map_server image with a ``crs`` reads as the GeoTIFF does."""
import dataclasses
import math

import numpy as np
import pytest

import rasterio  # noqa: E402  Debian's python3-rasterio (make setup installs it; no skip)

from quadrivio_config import ConfigError  # noqa: E402
from quadrivio_description.geodesy import LocalFrame  # noqa: E402
from quadrivio_terrain.georaster import crs_to_local, local_to_crs  # noqa: E402
from quadrivio_terrain.terrain import TerrainParams, build_heightfield  # noqa: E402
from quadrivio_description.vehicle import load_vehicle  # noqa: E402
from quadrivio_navigation.costmap import Footprint  # noqa: E402
from quadrivio_navigation.maps import MapError, OCCUPIED, UNKNOWN, load_map, obstacles_from_grid  # noqa: E402
from quadrivio_navigation.planning import Planner, PlannerParams  # noqa: E402
from quadrivio_navigation.rollover import RolloverParams  # noqa: E402

FRAME = LocalFrame(45.478070, 9.227690, 165.0)  # the default site (config/site.yaml)
CRS = "EPSG:32633"  # a UTM zone whose grid north is 4.1 deg off true north here
VEHICLE = load_vehicle()
BUILDINGS = ((5.0, -14.0, 8.0, 6.0), (-14.0, 10.0, 6.0, 10.0))  # local (east, north, width, depth) [m]


def terrain(e, n):
    """A ridge across the site at east = 10 m, too steep to drive but for a notch at north = 8 m."""
    ridge = 4.0 * np.exp(-((e - 10.0) / 1.5) ** 2)
    notch = np.clip((np.abs(n - 8.0) - 3.0) / 8.0, 0.0, 1.0)
    return 240.0 + ridge * notch


def corner(half):
    x0, y0 = local_to_crs(FRAME, CRS, np.array([0.0]), np.array([0.0]))
    return float(x0[0]) - half, float(y0[0]) + half


def pixel_grid(west, north, n, pixel):
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    return crs_to_local(FRAME, CRS, west + cols * pixel, north - rows * pixel)


def survey(tmp_path):
    """The drone's products: a DEM (1 m, float32) and a map (0.25 m, 8-bit: white free,
    black buildings and a border wall), both GeoTIFFs in UTM 33N."""
    from rasterio.transform import from_origin

    west, north = corner(70.0)
    E, N = pixel_grid(west, north, 140, 1.0)
    with rasterio.open(tmp_path / "dem.tif", "w", driver="GTiff", height=140, width=140, count=1, dtype="float32",
                       crs=CRS, transform=from_origin(west, north, 1.0, 1.0)) as ds:
        ds.write(terrain(E, N).astype("float32"), 1)
    west, north = corner(40.0)
    E, N = pixel_grid(west, north, 320, 0.25)
    img = np.full(E.shape, 255, "uint8")
    for e, n, w, d in BUILDINGS:
        img[(np.abs(E - e) < w / 2) & (np.abs(N - n) < d / 2)] = 0
    img[(np.abs(E) > 28.0) | (np.abs(N) > 28.0)] = 0  # the site's fence
    with rasterio.open(tmp_path / "map.tif", "w", driver="GTiff", height=320, width=320, count=1, dtype="uint8",
                       crs=CRS, transform=from_origin(west, north, 0.25, 0.25)) as ds:
        ds.write(img, 1)
    (tmp_path / "map.yaml").write_text("image: map.tif\nresolution: 0.25\noccupied_thresh: 0.65\n"
                                       "free_thresh: 0.196\nnegate: 0\n")
    return str(tmp_path / "dem.tif"), str(tmp_path / "map.yaml"), img, (west, north)


def footprint_points(fp: Footprint, pose, step=0.1):
    """Points covering the vehicle's rectangle at ``pose``."""
    c = fp.corners(*pose)
    u, v = c[1] - c[0], c[3] - c[0]
    a, b = np.meshgrid(np.linspace(0, 1, int(np.hypot(*u) / step) + 2), np.linspace(0, 1, int(np.hypot(*v) / step) + 2))
    return c[0] + a.ravel()[:, None] * u + b.ravel()[:, None] * v


def inside_blocks(points, blocks):
    hit = np.zeros(len(points), bool)
    for b in blocks:
        dx, dy = points[:, 0] - b.x, points[:, 1] - b.y
        if b.kind == "cylinder":
            hit |= np.hypot(dx, dy) <= b.size_x / 2
        else:
            c, s = math.cos(b.yaw), math.sin(b.yaw)
            hit |= (np.abs(c * dx + s * dy) <= b.size_x / 2) & (np.abs(-s * dx + c * dy) <= b.size_y / 2)
    return hit


def test_the_survey_drives_the_simulation_and_the_plan_alike(tmp_path):
    dem, map_yaml, _, _ = survey(tmp_path)
    grid = load_map(map_yaml, FRAME)
    assert "georeferenced" in grid.summary and not grid.warnings
    for e, n, w, d in BUILDINGS:  # where the survey put them, in the map frame
        assert grid.value_at(e, n) == OCCUPIED
        assert grid.value_at(e + w / 2 + 0.6, n) == 0
    heights = build_heightfield(TerrainParams(kind="geotiff", image=dem, size=120.0, resolution=0.5),
                                np.random.default_rng(0), FRAME)
    assert 3.5 < heights.height(10.0, -10.0) <= 4.0  # the 4 m ridge (1 m pixels cut its crest), relative to the origin
    planner = Planner(grid, VEHICLE, dataclasses.replace(PlannerParams(planner="lattice"), budget=10.0),
                      heights.heights, RolloverParams())
    r = planner.plan((-20.0, -2.0, 0.0), (22.0, -2.0, 0.0))
    assert r.ok, r.reason
    # the simulator's obstacles from the same map: the path's footprint never enters one
    blocks = obstacles_from_grid(grid)
    fp = Footprint.from_vehicle(VEHICLE)
    for pose in r.poses[::5]:
        assert not inside_blocks(footprint_points(fp, pose), blocks).any(), f"footprint in a building at {pose}"
    # the simulator's ground from the same DEM: no pose where the ground is steeper than the limit
    for x, y, _ in r.poses:
        gx, gy = heights.gradient(x, y)
        assert math.hypot(gx, gy) < planner.max_slope, f"driven up a {math.hypot(gx, gy):.2f} slope at {x:.1f}, {y:.1f}"
    crossing = r.poses[np.argmin(np.abs(r.poses[:, 0] - 10.0))]
    assert abs(crossing[1] - 8.0) < 2.5  # through the notch


def test_a_map_server_image_with_a_crs_reads_as_the_geotiff(tmp_path):
    from PIL import Image

    _, map_yaml, img, (west, north) = survey(tmp_path)
    Image.fromarray(img).save(tmp_path / "map.png")
    south = north - 320 * 0.25
    (tmp_path / "plain.yaml").write_text(f"image: map.png\nresolution: 0.25\norigin: [{west:.3f}, {south:.3f}, 0.0]\n"
                                         f"crs: '{CRS}'\noccupied_thresh: 0.65\nfree_thresh: 0.196\nnegate: 0\n")
    a, b = load_map(map_yaml, FRAME), load_map(str(tmp_path / "plain.yaml"), FRAME)
    assert a.data.shape == b.data.shape and a.origin == pytest.approx(b.origin, abs=1e-3)  # origin written to 1 mm
    assert np.mean(a.data == b.data) > 0.999  # cells whose centre lies within that mm of a pixel's edge may differ
    assert (a.data == UNKNOWN).any()  # the rotated survey does not fill its north-up bounding box


def test_bad_georeferenced_maps_are_named(tmp_path):
    survey(tmp_path)
    (tmp_path / "both.yaml").write_text("image: map.tif\nresolution: 0.25\norigin: [0, 0, 0]\n"
                                        "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    with pytest.raises(MapError, match="places itself"):
        load_map(str(tmp_path / "both.yaml"), FRAME)
    (tmp_path / "crs.yaml").write_text("image: map.png\nresolution: 0.25\norigin: [0, 0, 0]\ncrs: 'EPSG:999999'\n"
                                       "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    from PIL import Image

    Image.fromarray(np.zeros((4, 4), "uint8")).save(tmp_path / "map.png")
    with pytest.raises(MapError, match="not known to PROJ"):
        load_map(str(tmp_path / "crs.yaml"), FRAME)
    (tmp_path / "yaw.yaml").write_text("image: map.png\nresolution: 0.25\norigin: [0, 0, 0.3]\ncrs: 'EPSG:32632'\n"
                                       "occupied_thresh: 0.65\nfree_thresh: 0.196\n")
    with pytest.raises(MapError, match="yaw must be 0"):
        load_map(str(tmp_path / "yaw.yaml"), FRAME)
    with pytest.raises(ConfigError, match="no height"):  # a terrain larger than the survey
        build_heightfield(TerrainParams(kind="geotiff", image=str(tmp_path / "dem.tif"), size=400.0),
                          np.random.default_rng(0), FRAME)
