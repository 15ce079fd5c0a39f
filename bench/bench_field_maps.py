"""Benchmark: both planners on maps like the original vehicle's (issue 27's targets).

The original planner's maps are RGBA hillshades at 1 m per pixel, 50-650 m, with trees in
black. Two such maps are made here (seeded): 400 m and 650 m, greys 150-230 of a shaded
relief, opaque, with clumps of black trees (about a quarter of the cells, free space in many
pieces). Each is written as an RGBA PNG with a map_server YAML (``mode: scale``,
``occupied_thresh`` 0.9, ``free_thresh`` 0.8: the alpha channel left out of the average) and
read back through ``load_map``, the image path every node uses.

Pairs: start and goal poses drawn uniformly, free with 0.5 m to spare, at least 40 % of the
map's side apart, in one piece of free space, and *feasible*: the lattice plans them with a
60 s reference budget. On each, the lattice and OMPL (``planner: ompl`` with its hand-over
to the lattice) plan at their default budget (config/planner.yaml). Pairs in different
pieces are timed being refused. Keys:

* ``field_feasible_pairs``, ``field_lattice_planned``, ``field_ompl_planned`` (of them, at
  the default budget; ``field_ompl_alone_planned``: OMPL's own solutions, before any
  hand-over), ``field_collisions`` (poses of any returned path whose exact footprint touches
  an occupied cell);
* ``field_disconnected_refused`` of ``field_disconnected_pairs``, and
  ``field_disconnected_refusal_ms_max`` (target < 100), ``..._first_ms`` (the first request
  on a map, which computes its pieces; the worse map); on a map whose roomy poses all lie in
  one piece no disconnected pair is drawn (20000 tries);
* ``field_map_load_s`` per map.

Writes bench/results/field_maps.json and field_maps.png (the maps, the paths, the pairs).
``--pairs N`` feasible pairs per map (default 5: 10 in all), ``--quick`` (the 400 m map only).
"""
import argparse
import dataclasses
import math
import os
import sys
import tempfile
import time

import numpy as np

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.maps import load_map
from quadrivio_navigation.plan_cli import load_params
from quadrivio_navigation.planning import Planner
from quadrivio_runtime.files import atomic_path

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, machine, write_result  # noqa: E402

MAPS = {"400m": dict(size=400, seed=41, clumps=800), "650m": dict(size=650, seed=65, clumps=2100)}
REFERENCE_BUDGET = 60.0  # [s]
CLEARANCE = 0.5  # [m]


def hillshade(size: int, seed: int, clumps: int) -> np.ndarray:
    """RGBA pixels (size x size x 4, row 0 the top): a shaded relief with clumps of black trees."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:size, 0:size].astype(float)
    grey = 190.0 + 25.0 * np.sin(xx / 37.0 + 1.3) * np.cos(yy / 23.0) + 15.0 * np.sin((xx + 2 * yy) / 11.0)
    px = np.zeros((size, size, 4))
    px[..., :3] = np.clip(grey, 150, 230)[..., None]
    px[..., 3] = 255
    for _ in range(clumps):
        cy, cx = rng.uniform(0, size, 2)
        radius = rng.uniform(3.0, 9.0)
        for _ in range(int(rng.integers(3, 12))):
            a, d = rng.uniform(0, 2 * math.pi), radius * math.sqrt(rng.uniform())
            r, c = int(cy + d * math.sin(a)), int(cx + d * math.cos(a))
            k = int(rng.integers(1, 3))  # crowns of 1-2 m radius
            if 0 <= r < size and 0 <= c < size:  # (a negative slice end would blacken whole rows)
                px[max(r - k, 0):r + k + 1, max(c - k, 0):c + k + 1, :3] = 0.0
    return px


def write_map(folder: str, name: str, px: np.ndarray) -> str:
    from PIL import Image

    Image.fromarray(px.astype(np.uint8), "RGBA").save(os.path.join(folder, f"{name}.png"))
    h = px.shape[0]
    path = os.path.join(folder, f"{name}.yaml")
    with open(path, "w") as fh:
        fh.write(f"image: {name}.png\nresolution: 1.0\norigin: [{-h / 2}, {-h / 2}, 0.0]\nmode: scale\n"
                 "occupied_thresh: 0.9\nfree_thresh: 0.8\nnegate: 0\n")
    return path


def collisions(planner, poses) -> int:
    exact = Footprint.from_vehicle(planner.vehicle)
    return sum(1 for x, y, th in poses if planner.cost.collides(exact, x, y, th))


def draw(planner, roomy, rng, size, connected: bool, tries: int = 20000):
    """A pair of roomy poses far apart, in one piece of free space or not; None after ``tries``."""
    h = 0.5 * size - 5.0
    for _ in range(tries):
        s = (rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(-math.pi, math.pi))
        g = (rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(-math.pi, math.pi))
        if math.hypot(s[0] - g[0], s[1] - g[1]) < 0.4 * size or roomy.check_pose(s, "s") or roomy.check_pose(g, "g"):
            continue
        if (not planner.check_connected(s, g)) == connected:
            return s, g
    return None


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--pairs", type=int, default=5, help="feasible pairs per map")
    ap.add_argument("--disconnected", type=int, default=5, help="disconnected pairs per map")
    ap.add_argument("--quick", action="store_true", help="the 400 m map only")
    args = ap.parse_args()
    params = load_params([])
    vehicle = load_vehicle()
    result = {"machine": machine(), "budget_s": params.budget, "reference_budget_s": REFERENCE_BUDGET,
              "ompl_hand_over": params.ompl.hand_over}
    shown = {}
    counts = dict(feasible=0, lattice=0, ompl=0, ompl_alone=0, collisions=0, disc=0, refused=0)
    refusals, firsts = [], []
    folder = tempfile.mkdtemp(prefix="field_maps-")
    for name, spec in MAPS.items():
        if args.quick and name != "400m":
            continue
        px = hillshade(spec["size"], spec["seed"], spec["clumps"])
        t = time.perf_counter()
        grid = load_map(write_map(folder, name, px))
        result[f"field_map_load_s_{name}"] = time.perf_counter() - t
        print(f"[bench] {grid.summary}", flush=True)
        planner = Planner(grid, vehicle, params)
        roomy = Planner(grid, vehicle, dataclasses.replace(params, cost=dataclasses.replace(
            params.cost, padding=params.cost.padding + CLEARANCE)))
        rng = np.random.default_rng(spec["seed"] + 7)
        # the first request on a map computes its pieces: timed on its own
        t = time.perf_counter()
        planner.check_connected((0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
        firsts.append(1e3 * (time.perf_counter() - t))
        map_refusals = []
        for k in range(args.disconnected):
            pair = draw(planner, roomy, rng, spec["size"], connected=False)
            if pair is None:
                print("[bench]   no more disconnected pairs drawn in 20000 tries", flush=True)
                break
            s, g = pair
            for kind in ("lattice", "ompl"):
                r = planner.plan(s, g, planner=kind)
                counts["disc"] += 1
                counts["refused"] += int(not r.ok and "different pieces" in r.reason)
                map_refusals.append(1e3 * r.planning_time)
        refusals += map_refusals
        print(f"[bench]   the map's pieces in {firsts[-1]:.0f} ms; {len(map_refusals)} disconnected requests refused"
              + (f" in {max(map_refusals):.1f} ms at most" if map_refusals else ""), flush=True)
        paths = []
        tried = 0
        feasible = 0
        while feasible < args.pairs and tried < 10 * args.pairs:
            tried += 1
            s, g = draw(planner, roomy, rng, spec["size"], connected=True)  # (one piece holds most of the map)
            ref = planner.plan(s, g, REFERENCE_BUDGET, planner="lattice")
            if not ref.ok:
                print(f"[bench]   pair not feasible ({ref.reason[:60]}): drawn again", flush=True)
                continue
            feasible += 1
            row = {}
            for kind in ("lattice", "ompl"):
                r = planner.plan(s, g, planner=kind)
                c = collisions(planner, r.poses) if r.ok else 0
                counts["collisions"] += c
                counts[kind] += int(r.ok)
                if kind == "ompl":
                    counts["ompl_alone"] += int(r.ok and r.planner == "ompl")
                row[kind] = (r.ok, r.planner, r.planning_time, c)
                if r.ok:
                    paths.append((kind, r.poses))
            print(f"[bench]   pair {feasible}/{args.pairs} ({math.hypot(s[0] - g[0], s[1] - g[1]):.0f} m): "
                  f"lattice {'ok' if row['lattice'][0] else 'no path'} in {row['lattice'][2]:.2f} s, "
                  f"{row['ompl'][1]} {'ok' if row['ompl'][0] else 'no path'} in {row['ompl'][2]:.2f} s, "
                  f"collisions {row['lattice'][3] + row['ompl'][3]}", flush=True)
        counts["feasible"] += feasible
        shown[name] = (grid, paths)
    result.update({"field_feasible_pairs": counts["feasible"], "field_lattice_planned": counts["lattice"],
                   "field_ompl_planned": counts["ompl"], "field_ompl_alone_planned": counts["ompl_alone"],
                   "field_collisions": counts["collisions"], "field_disconnected_pairs": counts["disc"],
                   "field_disconnected_refused": counts["refused"],
                   "field_disconnected_refusal_ms_max": max(refusals) if refusals else None,
                   "field_disconnected_refusal_first_ms": max(firsts) if firsts else None})
    write_result("field_maps", result)
    plot(os.path.join(RESULTS, "field_maps.png"), shown)
    for k in sorted(result):
        if k.startswith("field_"):
            print(f"  {k:40s} {result[k]}")


def plot(path: str, shown) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(shown), figsize=(7 * len(shown), 7), squeeze=False)
    for ax, (name, (grid, paths)) in zip(axes[0], shown.items()):
        w, h = grid.size
        ox, oy, _ = grid.origin
        ax.imshow(grid.data >= 65, origin="lower", cmap="Greys", extent=(ox, ox + w, oy, oy + h))
        for kind, poses in paths:
            ax.plot(poses[:, 0], poses[:, 1], "-", lw=1.0, color="tab:blue" if kind == "lattice" else "tab:orange",
                    alpha=0.8, label=kind)
            ax.plot(poses[0, 0], poses[0, 1], "go", ms=4)
            ax.plot(poses[-1, 0], poses[-1, 1], "mo", ms=4)
        handles, labels = ax.get_legend_handles_labels()
        seen = dict(zip(labels, handles))
        ax.legend(seen.values(), seen.keys(), loc="upper right", fontsize=8)
        ax.set_title(f"{name}: the lattice (blue) and OMPL (orange) at the default budget", fontsize=9)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    main()
