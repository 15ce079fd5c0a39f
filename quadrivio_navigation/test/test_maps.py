"""Maps in map_server's format: thresholds, modes, negate, channels, origin, bad files,
large maps, and the obstacles the simulator builds from them."""
import math
import os

import numpy as np
import pytest
import yaml
from PIL import Image

from quadrivio_navigation.maps import (FREE, OCCUPIED, UNKNOWN, MapError, OccupancyGrid, load_map,
                                       obstacles_from_grid, read_metadata, resolve_map_file, save_map)


def write(tmp_path, pixels, pil_mode=None, name="map.png", **meta):
    """A map YAML next to an image made of ``pixels`` (uint8, HxW or HxWxC)."""
    img = Image.fromarray(np.asarray(pixels, dtype=np.uint8), pil_mode)
    img.save(tmp_path / name)
    data = {"image": name, "resolution": 0.5, "origin": [-1.0, -2.0, 0.0], "occupied_thresh": 0.65,
            "free_thresh": 0.196, "negate": 0}
    data.update(meta)
    (tmp_path / "map.yaml").write_text(yaml.safe_dump(data))
    return str(tmp_path / "map.yaml")


def test_trinary_thresholds_and_row_order(tmp_path):
    # top row black (occupied), middle grey (unknown), bottom white (free)
    px = np.array([[0, 0, 0], [128, 128, 128], [255, 255, 255]])
    grid = load_map(write(tmp_path, px))
    assert grid.data.shape == (3, 3)
    assert (grid.data[0] == FREE).all()  # row 0 is the image's bottom
    assert (grid.data[1] == UNKNOWN).all()
    assert (grid.data[2] == OCCUPIED).all()
    assert grid.resolution == 0.5 and grid.origin == (-1.0, -2.0, 0.0)
    # cell (row 2, col 1) holds the point 0.75 m right and 2.25 m up of the origin
    assert grid.value_at(-1.0 + 0.75, -2.0 + 1.25) == OCCUPIED
    assert grid.value_at(-1.0 + 0.75, -2.0 + 0.25) == FREE
    assert grid.value_at(-1.0 - 0.1, 0.0) is None


def test_negate_swaps_black_and_white(tmp_path):
    px = np.array([[0, 255]])
    grid = load_map(write(tmp_path, px, negate=1))
    assert grid.data[0].tolist() == [FREE, OCCUPIED]


def test_scale_mode_values_between_thresholds(tmp_path):
    # p = (255 - c) / 255: c = 128 -> p = 0.498, between free 0.196 and occupied 0.65
    px = np.array([[128, 0, 255]])
    grid = load_map(write(tmp_path, px, **{"mode": "scale"}))
    p = (255 - 128) / 255.0
    expect = int(1 + 98 * (p - 0.196) / (0.65 - 0.196))
    assert grid.data[0].tolist() == [expect, OCCUPIED, FREE]


def test_raw_mode_and_unknown(tmp_path):
    px = np.array([[0, 50, 100, 255]])
    grid = load_map(write(tmp_path, px, **{"mode": "raw"}))
    assert grid.data[0].tolist() == [0, 50, 100, UNKNOWN]
    px = np.array([[0, 180]])
    with pytest.raises(MapError, match="raw mode"):
        load_map(write(tmp_path, px, **{"mode": "raw"}))


def test_rgb_channels_are_averaged_like_map_server(tmp_path):
    # an aerial image: a dark-green tree (mean 40), a grey road (mean 200), a red roof (mean 85)
    px = np.array([[[20, 80, 20], [200, 200, 200], [255, 0, 0]]])
    grid = load_map(write(tmp_path, px, pil_mode="RGB", occupied_thresh=0.6, free_thresh=0.3))
    # tree: p = 0.84 occupied; road: p = 0.22 free; roof: p = 0.67 occupied
    assert grid.data[0].tolist() == [OCCUPIED, FREE, OCCUPIED]


def test_rgba_alpha_counts_in_trinary_but_not_in_scale(tmp_path):
    # a white pixel made fully transparent: trinary averages alpha in (map_server's rule)
    px = np.array([[[255, 255, 255, 0], [0, 0, 0, 255]]])
    tri = load_map(write(tmp_path, px, pil_mode="RGBA"))
    mean = (255 * 3 + 0) / 4.0  # 191.25 -> p = 0.25: between the thresholds, unknown
    assert (255 - mean) / 255 > 0.196 and tri.data[0].tolist() == [UNKNOWN, OCCUPIED]
    sc = load_map(write(tmp_path, px, pil_mode="RGBA", **{"mode": "scale"}))
    assert sc.data[0].tolist() == [FREE, OCCUPIED]  # colour only: white is free


def test_pgm_and_16_bit_and_palette(tmp_path):
    grid = OccupancyGrid(np.array([[0, 100], [-1, 0]], dtype=np.int8), 0.1, (0.0, 0.0, 0.0))
    path = save_map(grid, str(tmp_path / "saved.yaml"))
    back = load_map(path)
    assert back.data.tolist() == grid.data.tolist() and back.resolution == 0.1
    # 16-bit grey PNG: full scale black and white
    img = Image.fromarray(np.array([[0, 65535]], dtype=np.uint16))
    img.save(tmp_path / "deep.png")
    (tmp_path / "deep.yaml").write_text(yaml.safe_dump({"image": "deep.png", "resolution": 1.0,
                                                         "origin": [0, 0, 0], "occupied_thresh": 0.65,
                                                         "free_thresh": 0.2, "negate": 0}))
    assert load_map(str(tmp_path / "deep.yaml")).data[0].tolist() == [OCCUPIED, FREE]
    pal = Image.fromarray(np.array([[0, 1]], dtype=np.uint8), "P")
    pal.putpalette([0, 0, 0, 255, 255, 255] + [0] * 762)
    pal.save(tmp_path / "pal.png")
    (tmp_path / "pal.yaml").write_text(yaml.safe_dump({"image": "pal.png", "resolution": 1.0, "origin": [0, 0, 0],
                                                       "occupied_thresh": 0.65, "free_thresh": 0.2, "negate": 0}))
    assert load_map(str(tmp_path / "pal.yaml")).data[0].tolist() == [OCCUPIED, FREE]


@pytest.mark.parametrize("meta, message", [
    ({"resolution": -1.0}, "resolution"),
    ({"resolution": "fine"}, "resolution"),
    ({"origin": [0, 0]}, "origin"),
    ({"origin": [0, float("nan"), 0]}, "origin"),
    ({"occupied_thresh": 0.1}, "thresholds"),
    ({"negate": 2}, "negate"),
    ({"mode": "fancy"}, "mode"),
    ({"occupied_treshold": 0.6}, "unknown key"),
    ({"image": "missing.png"}, "file not found"),
])
def test_bad_yaml_names_the_problem(tmp_path, meta, message):
    path = write(tmp_path, np.zeros((2, 2)), **meta)
    with pytest.raises(MapError, match=message):
        load_map(path)


def test_bad_files(tmp_path):
    with pytest.raises(MapError, match="file not found"):
        load_map(str(tmp_path / "nope.yaml"))
    (tmp_path / "broken.yaml").write_text("image: [unclosed\n")
    with pytest.raises(MapError, match="malformed YAML"):
        read_metadata(str(tmp_path / "broken.yaml"))
    (tmp_path / "list.yaml").write_text("- 1\n- 2\n")
    with pytest.raises(MapError, match="must be a mapping"):
        read_metadata(str(tmp_path / "list.yaml"))
    (tmp_path / "junk.png").write_bytes(b"not an image at all")
    (tmp_path / "junk.yaml").write_text(yaml.safe_dump({"image": "junk.png", "resolution": 1.0, "origin": [0, 0, 0],
                                                        "occupied_thresh": 0.65, "free_thresh": 0.2, "negate": 0}))
    with pytest.raises(MapError, match="cannot read"):
        load_map(str(tmp_path / "junk.yaml"))


def test_rotated_origin_frames():
    grid = OccupancyGrid(np.zeros((10, 20), np.int8), 0.5, (3.0, 4.0, math.pi / 2))
    gx, gy, gth = grid.to_grid_frame(3.0, 5.0, math.pi / 2)  # 1 m along the grid's x (map's +y)
    assert (gx, gy) == pytest.approx((1.0, 0.0)) and gth == pytest.approx(0.0)
    x, y, th = grid.to_map_frame(gx, gy, gth)
    assert (x, y, th) == pytest.approx((3.0, 5.0, math.pi / 2))
    assert grid.contains(2.0, 7.0) and not grid.contains(4.0, 5.0)


@pytest.mark.parametrize("size, res", [((650, 500), 1.0), ((100, 100), 0.1)])
def test_large_maps_load(tmp_path, size, res):
    w, h = int(size[0] / res), int(size[1] / res)
    px = np.full((h, w), 254, np.uint8)
    px[h // 3:h // 2, w // 4:w // 3] = 0
    img = Image.fromarray(px)
    img.save(tmp_path / "big.pgm")
    (tmp_path / "big.yaml").write_text(yaml.safe_dump({"image": "big.pgm", "resolution": res, "origin": [0, 0, 0],
                                                       "occupied_thresh": 0.65, "free_thresh": 0.196, "negate": 0}))
    grid = load_map(str(tmp_path / "big.yaml"))
    assert grid.size == pytest.approx(size)
    assert int((grid.data == OCCUPIED).sum()) == int((px == 0).sum())


def test_relative_scenario_paths(tmp_path):
    assert resolve_map_file("maps/a.yaml", "/x/scenarios/s.yaml") == "/x/scenarios/maps/a.yaml"
    assert resolve_map_file("/abs/a.yaml", "/x/s.yaml") == "/abs/a.yaml"
    assert resolve_map_file("", "/x/s.yaml") == ""


def test_obstacles_cover_every_occupied_cell_and_trees_are_cylinders():
    data = np.zeros((50, 60), np.int8)
    data[10:12, 10:12] = OCCUPIED  # a tree: 2 x 2 cells = 0.4 m
    data[30:33, 5:50] = OCCUPIED  # a wall
    data[40:48, 40:44] = OCCUPIED  # a building
    data[40:44, 44:50] = OCCUPIED  # an L-shaped annex
    grid = OccupancyGrid(data, 0.2, (10.0, -5.0, 0.0))
    blocks = obstacles_from_grid(grid, tree_size=1.0)
    trees = [b for b in blocks if b.kind == "cylinder"]
    boxes = [b for b in blocks if b.kind == "box"]
    assert len(trees) == 1 and len(boxes) <= 4
    assert trees[0].x == pytest.approx(10.0 + 11 * 0.2) and trees[0].y == pytest.approx(-5.0 + 11 * 0.2)
    # every occupied cell centre lies inside some obstacle, and no box covers a free cell
    rows, cols = np.nonzero(data)
    for r, c in zip(rows, cols):
        x, y = 10.0 + (c + 0.5) * 0.2, -5.0 + (r + 0.5) * 0.2
        assert any(inside(b, x, y) for b in blocks), (r, c)
    rows, cols = np.nonzero(data == 0)
    for r, c in zip(rows[::7], cols[::7]):
        x, y = 10.0 + (c + 0.5) * 0.2, -5.0 + (r + 0.5) * 0.2
        assert not any(inside(b, x, y) for b in boxes), (r, c)


def inside(b, x, y):
    if b.kind == "cylinder":
        return math.hypot(x - b.x, y - b.y) <= 0.5 * b.size_x + 1e-9
    return abs(x - b.x) <= 0.5 * b.size_x + 1e-9 and abs(y - b.y) <= 0.5 * b.size_y + 1e-9


def test_scenario_maps_are_up_to_date():
    """scenarios/maps/* are what tools/make_maps.py draws (regenerate after changing it)."""
    import importlib.util

    root = os.path.normpath(os.path.join(os.path.dirname(__file__), "..", ".."))
    spec = importlib.util.spec_from_file_location("make_maps", os.path.join(root, "tools", "make_maps.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    for name, make in mod.MAPS.items():
        stored = load_map(os.path.normpath(os.path.join(root, "scenarios", "maps", f"{name}.yaml")))
        assert np.array_equal(stored.data, make().data), name


def hillshade_with_trees(rng, size=120, trees=40):
    """An RGBA hillshade (greys 150-230, opaque) with black trees: the original vehicle's maps."""
    yy, xx = np.mgrid[0:size, 0:size]
    grey = 190 + 40 * np.sin(xx / 9.0) * np.cos(yy / 13.0)
    px = np.zeros((size, size, 4))
    px[..., 0] = px[..., 1] = px[..., 2] = grey
    px[..., 3] = 255
    for _ in range(trees):
        r, c = rng.integers(2, size - 3, 2)
        px[r - 1:r + 2, c - 1:c + 2, :3] = 0
    return px


def test_a_misread_rgba_hillshade_warns_and_says_what_it_would_hold_otherwise(tmp_path):
    """Thresholds that look ordinary (0.9 / 0.8) with the alpha channel averaged in (map_server's
    trinary rule): black scores (255 - 255/4) / 255 = 0.75 and every cell is free. Loading says
    so, names the mode, the thresholds and negate, and what the image holds read otherwise."""
    px = hillshade_with_trees(np.random.default_rng(3))
    grid = load_map(write(tmp_path, px, "RGBA", occupied_thresh=0.9, free_thresh=0.8))
    assert (grid.data != OCCUPIED).all()  # read as map_server reads it
    assert "occupied 0 %" in grid.summary and "mode trinary" in grid.summary
    assert len(grid.warnings) == 1
    w = grid.warnings[0]
    assert "likely misread" in w and "no cell is occupied" in w and "darkest pixels come out free" in w
    assert "occupied_thresh 0.9" in w and "free_thresh 0.8" in w and "negate 0" in w and "alpha channel" in w
    assert "without the alpha channel in the average (mode: scale) occupied 2 %" in w or \
        "without the alpha channel in the average (mode: scale) occupied 3 %" in w, w
    # read without the alpha channel, the same image holds its trees and loads without a warning
    ok = load_map(write(tmp_path, px, "RGBA", occupied_thresh=0.9, free_thresh=0.8, mode="scale"))
    assert (ok.data == OCCUPIED).sum() == (px[..., 0] == 0).sum() and ok.warnings == ()


def test_an_ordinary_map_says_what_it_holds_without_warnings(tmp_path):
    px = np.full((20, 30), 255)
    px[5:8, 10:12] = 0
    grid = load_map(write(tmp_path, px))
    assert grid.warnings == ()
    assert grid.summary.endswith("(mode trinary, occupied_thresh 0.65, free_thresh 0.196, negate 0)")
    assert "30 x 20 cells at 0.5 m: occupied 1 %, free 99 %, unknown 0 %" in grid.summary


@pytest.mark.parametrize("pixels, needle", [(np.full((10, 10), 255), "no cell is occupied"),
                                            (np.full((10, 10), 128), "every cell is unknown")])
def test_an_empty_or_unknown_map_warns(tmp_path, pixels, needle):
    grid = load_map(write(tmp_path, pixels))
    assert len(grid.warnings) == 1 and needle in grid.warnings[0]



def test_plan_says_the_map_warning_on_its_output(tmp_path, capsys):
    """`plan` on a misread map: the warning on stderr, in plan.json and on plan.png (drawn)."""
    import json

    from quadrivio_navigation import plan_cli

    px = hillshade_with_trees(np.random.default_rng(5), size=60, trees=10)
    path = write(tmp_path, px, "RGBA", occupied_thresh=0.9, free_thresh=0.8, resolution=1.0, origin=[0.0, 0.0, 0.0])
    out = tmp_path / "out"
    plan_cli.main([path, "--start", "5,5,0", "--goal", "45,45,0", "--out", str(out)])
    err = capsys.readouterr().err
    assert "WARNING: map" in err and "likely misread" in err
    info = json.loads((out / "plan.json").read_text())
    assert len(info["map_warnings"]) == 1 and "occupied 0 %" in info["map_summary"]
    assert (out / "plan.png").stat().st_size > 10_000
