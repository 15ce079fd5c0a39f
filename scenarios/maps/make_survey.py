#!/usr/bin/env python3
"""Writes the synthetic drone survey of ``scenarios/surveyed_site.yaml``: ``survey_dem.tif``
(a DEM, 1 m, float32 metres) and ``survey_map.tif`` (a map, 0.25 m, 8-bit grey: white free,
black buildings, trees and the fence), both GeoTIFFs in UTM zone 32N (EPSG:32632), the
projected CRS a survey of the default site (Milan, config/site.yaml) comes in.

The site, in the map frame (east, north about the datum): a 4 m ridge across it at
east = 12 m with flanks steeper than the roll-over limit, crossable only at a notch around
north = 10 m; a shed and a barn; a row of trees; a fence 2 m inside the survey's edge.

    python3 scenarios/maps/make_survey.py [OUT_DIR]   (default: this file's folder)
"""
import os
import sys

import numpy as np
import rasterio
from rasterio.transform import from_origin

from quadrivio_terrain.georaster import crs_to_local, local_to_crs
from quadrivio_description.site import load_site

CRS = "EPSG:32632"
HALF = 45.0  # [m] the survey covers +-45 m about the datum (the map), the DEM +-70 m
BUILDINGS = ((0.0, -18.0, 10.0, 7.0), (-24.0, 16.0, 8.0, 12.0))  # (east, north, width, depth) [m]
TREES = [(28.0, n) for n in np.arange(-30.0, 31.0, 6.0)]  # a row east of the ridge
TREE_RADIUS = 0.5


def ground(e, n):
    ridge = 4.0 * np.exp(-((e - 12.0) / 1.5) ** 2)
    notch = np.clip((np.abs(n - 10.0) - 3.0) / 8.0, 0.0, 1.0)
    return 180.0 + 0.01 * e + 0.02 * n + ridge * notch


def write(out: str) -> None:
    frame = load_site().local_frame()
    x0, y0 = local_to_crs(frame, CRS, np.array([0.0]), np.array([0.0]))
    # the DEM: 1 m pixels, +-70 m
    west, north, px, n = float(np.floor(x0[0] - 70.0)), float(np.ceil(y0[0] + 70.0)), 1.0, 140
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    E, N = crs_to_local(frame, CRS, west + cols * px, north - rows * px)
    with rasterio.open(os.path.join(out, "survey_dem.tif"), "w", driver="GTiff", height=n, width=n, count=1,
                       dtype="float32", crs=CRS, transform=from_origin(west, north, px, px), compress="deflate",
                       nodata=-9999.0) as ds:
        ds.write(ground(E, N).astype("float32"), 1)
    # the map: 0.25 m pixels, +-45 m
    west, north, px, n = float(np.floor(x0[0] - HALF)), float(np.ceil(y0[0] + HALF)), 0.25, int(2 * HALF / 0.25) + 8
    cols, rows = np.meshgrid(np.arange(n) + 0.5, np.arange(n) + 0.5)
    E, N = crs_to_local(frame, CRS, west + cols * px, north - rows * px)
    img = np.full(E.shape, 255, "uint8")
    for e, nn, w, d in BUILDINGS:
        img[(np.abs(E - e) < w / 2) & (np.abs(N - nn) < d / 2)] = 0
    for e, nn in TREES:
        img[np.hypot(E - e, N - nn) < TREE_RADIUS] = 0
    img[(np.abs(E) > HALF - 2.0) | (np.abs(N) > HALF - 2.0)] = 0
    with rasterio.open(os.path.join(out, "survey_map.tif"), "w", driver="GTiff", height=n, width=n, count=1,
                       dtype="uint8", crs=CRS, transform=from_origin(west, north, px, px), compress="deflate") as ds:
        ds.write(img, 1)


if __name__ == "__main__":
    write(sys.argv[1] if len(sys.argv) > 1 else os.path.dirname(os.path.abspath(__file__)))
