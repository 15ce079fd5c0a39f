"""``rosrun quadrivio_navigation plan MAP.yaml --start X,Y,YAW --goal X,Y,YAW [--planner lattice|ompl] --out DIR``

Plans once, offline, on a map_server map (a georeferenced one too: a GeoTIFF, or an image
with a ``crs``, placed about ``--site``'s datum), with ``--dem SURVEY.tif`` on the site's
terrain (slope cost, slopes beyond the roll-over limit blocked), and writes:

* ``DIR/path.csv``: ``x, y, yaw, direction, s`` per pose (map frame, m and rad;
  direction +1 forward, -1 reverse for the motion to the next pose; s the arc length);
* ``DIR/plan.png``: the map, the path (forward blue, reverse red), the vehicle's
  footprint along it, the start and goal, and the states the search expanded;
* ``DIR/plan.json``: the planner, success or the reason of failure, cost, length,
  time to the first solution, planning time, expansions, cusps, each improvement.

Exit status: 0 a path was found, 1 no path (the reason is printed and in plan.json),
2 bad input (map, poses, parameters). Nothing is half-written: each file is written to
a temporary name and moved into place.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from typing import List, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, from_mapping, load_yaml, replace_nested
from quadrivio_description.vehicle import load_vehicle
from quadrivio_runtime.files import atomic_path, atomic_write

from .maps import load_map
from .planning import PlannerParams, Planner, PlanResult


def parse_pose(text: str, what: str) -> Tuple[float, float, float]:
    parts = text.replace(" ", "").split(",")
    try:
        vals = tuple(float(p) for p in parts)
    except ValueError:
        vals = ()
    if len(vals) != 3 or not all(map(math.isfinite, vals)):
        raise ConfigError(f"--{what} {text!r}: expected X,Y,YAW (metres, metres, radians)")
    return vals  # type: ignore[return-value]


def default_params_file() -> str:
    from .package import package_file

    return package_file("config", "planner.yaml")


def load_params(files: List[str], overrides: Optional[dict] = None) -> PlannerParams:
    """Planner parameters: the package's ``config/planner.yaml``, then each file in turn."""
    import dataclasses

    base = default_params_file()
    raw = load_yaml(base)
    names = {f.name for f in dataclasses.fields(PlannerParams)}
    p = from_mapping(PlannerParams, {k: v for k, v in raw.items() if k in names}, base)
    for f in files:
        p = replace_nested(p, load_yaml(f), f)
    if overrides:
        p = replace_nested(p, overrides, "command line")
    return p


def write_csv(path: str, r: PlanResult) -> None:
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(r.poses[:, 0]), np.diff(r.poses[:, 1])))])

    rows = [f"{x:.4f},{y:.4f},{th:.5f},{int(d)},{si:.4f}\n" for (x, y, th), d, si in zip(r.poses, r.directions, s)]
    atomic_write(path, "x,y,yaw,direction,s\n" + "".join(rows))


def summary(r: PlanResult, start, goal) -> dict:
    def num(v):
        return None if v is None or (isinstance(v, float) and not math.isfinite(v)) else v

    return {"planner": r.planner, "ok": r.ok, "reason": r.reason, "note": r.note, "start": list(start), "goal": list(goal),
            "cost": num(r.cost), "length_m": num(r.length), "time_to_first_s": num(r.time_to_first),
            "planning_time_s": num(r.planning_time), "expansions": r.expansions, "cusps": r.cusps if r.ok else None,
            "poses": int(len(r.poses)), "goal_offset_m": r.goal_offset[0], "goal_offset_rad": r.goal_offset[1],
            "improvements": [{"time_s": t, "cost": c} for t, c in r.solutions]}


def plot(path: str, planner: Planner, r: PlanResult, start, goal, title: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Polygon

    grid = planner.grid
    fig, ax = plt.subplots(figsize=(9, 9))
    # the map as shown by rviz: free white, occupied black, unknown grey, costs between
    img = np.full(grid.data.shape, 0.85)
    d = grid.data.astype(float)
    img[d == 0] = 1.0
    between = (d > 0) & (d < 100)
    img[between] = 1.0 - 0.6 * d[between] / 100.0
    img[d >= planner.p.cost.lethal] = 0.0
    steep = (planner.cost.cost == 255) & (grid.data >= 0) & (grid.data < planner.p.cost.lethal)
    x0, y0, yaw = grid.origin
    w, h = grid.size
    rgb = np.dstack([img, img, img])
    rgb[steep] = (0.8, 0.55, 0.3)
    if abs(yaw) < 1e-9:
        ax.imshow(rgb, origin="lower", extent=(x0, x0 + w, y0, y0 + h), interpolation="nearest")
    else:  # a rotated map: draw the occupied cells as points
        rr, cc = np.nonzero(grid.data >= planner.p.cost.lethal)
        px, py, _ = grid.to_map_frame((cc + 0.5) * grid.resolution, (rr + 0.5) * grid.resolution)
        ax.plot(px, py, "s", color="k", markersize=1)
    if len(r.expanded):
        ax.plot(r.expanded[:, 0], r.expanded[:, 1], ".", color="orange", markersize=1, alpha=0.4,
                label=f"expanded ({r.expansions})")
    if r.ok:
        p, dirs = r.poses, r.directions
        for sign, colour, label in ((1, "tab:blue", "forward"), (-1, "tab:red", "reverse")):
            seg = np.where(dirs[:-1] == sign, 1.0, np.nan)
            xs = np.column_stack([p[:-1, 0], p[1:, 0], seg * 0 + np.nan]).ravel()
            ys = np.column_stack([p[:-1, 1], p[1:, 1], np.nan * seg]).ravel()
            keep = np.repeat(dirs[:-1] == sign, 3)
            if keep.any():
                ax.plot(xs[keep], ys[keep], "-", color=colour, lw=1.8, label=label)
        s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1])))])
        step = max(1.5, s[-1] / 40.0)
        marks = np.searchsorted(s, np.arange(0.0, s[-1], step))
        for i in list(marks) + [len(p) - 1]:
            ax.add_patch(Polygon(planner.footprint.corners(*p[i]), closed=True, fill=False, lw=0.6,
                                 ec="tab:green", alpha=0.8))
    for pose, colour, name in ((start, "tab:green", "start"), (goal, "tab:purple", "goal")):
        ax.add_patch(Polygon(planner.footprint.corners(*pose), closed=True, fill=True, alpha=0.5, fc=colour,
                             ec="k", label=name))
    status = (f"{r.planner}: {r.length:.1f} m, cost {r.cost:.1f}, first solution {1e3 * r.time_to_first:.0f} ms, "
              f"{r.cusps} cusp(s)" if r.ok else f"{r.planner}: FAILED: {r.reason}")
    ax.set_title(f"{title}\n{status}", fontsize=9)
    if grid.warnings:  # a map read as empty or misread says so on the picture itself
        import textwrap

        ax.text(0.01, 0.01, "\n".join(textwrap.wrap("MAP WARNING: " + grid.warnings[0], 110)), transform=ax.transAxes,
                fontsize=7, color="darkred", va="bottom", bbox=dict(fc="white", ec="darkred", alpha=0.85))
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_aspect("equal")
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="plan", description=__doc__.split("\n\n")[0])
    ap.add_argument("map", help="map_server YAML")
    ap.add_argument("--start", required=True, help="X,Y,YAW [m, m, rad] in the map frame")
    ap.add_argument("--goal", required=True, help="X,Y,YAW [m, m, rad]")
    ap.add_argument("--planner", choices=("lattice", "ompl"), default=None, help="default: planner.yaml's")
    ap.add_argument("--budget", type=float, default=None, help="time budget [s] (default: planner.yaml's)")
    ap.add_argument("--seed", type=int, default=None, help="seed of the sampling planners")
    ap.add_argument("--params", action="append", default=[], help="planner YAML overriding config/planner.yaml")
    ap.add_argument("--vehicle", default="", help="vehicle YAML (default: quadrivio_description's)")
    ap.add_argument("--dem", default="", help="the site's DEM, a GeoTIFF in any CRS: slopes cost, slopes steeper than the "
                                              "roll-over limit are obstacles")
    ap.add_argument("--dem-size", type=float, default=0.0,
                    help="side [m] of the DEM's square about the datum to use (default: the map's extent)")
    ap.add_argument("--site", default="", help="site YAML whose datum places georeferenced maps and DEMs "
                                               "(default: quadrivio_description's config/site.yaml)")
    ap.add_argument("--out", required=True, help="output folder")
    raw = [a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a]
    # "--start -3,2,0": a negative pose would read as an option; glue it to its flag
    glued = []
    for a in raw:
        if glued and glued[-1] in ("--start", "--goal") and a.startswith("-"):
            glued[-1] = f"{glued[-1]}={a}"
        else:
            glued.append(a)
    args = ap.parse_args(glued)
    try:
        start = parse_pose(args.start, "start")
        goal = parse_pose(args.goal, "goal")
        if args.budget is not None and not (args.budget > 0 and math.isfinite(args.budget)):
            raise ConfigError(f"--budget {args.budget}: must be a positive number of seconds")
        if args.seed is not None and args.seed < 0:
            raise ConfigError(f"--seed {args.seed}: must be a non-negative integer")
        over = {}
        if args.planner:
            over["planner"] = args.planner
        if args.seed is not None:
            over["seed"] = args.seed
        params = load_params(args.params, over)
        vehicle = load_vehicle(args.vehicle)
        from quadrivio_description.site import load_site

        frame = load_site(args.site).local_frame()
        grid = load_map(args.map, frame)
        print(f"[plan] {grid.summary}", flush=True)
        for warning in grid.warnings:
            print(f"[plan] WARNING: {warning}", file=sys.stderr, flush=True)
        heights, rollover = None, None
        if args.dem:
            from quadrivio_terrain.georaster import dem_heightfield
            from .rollover import RolloverParams

            w, h = grid.size
            ox, oy, _ = grid.origin
            size = args.dem_size or 2.0 * max(abs(ox), abs(oy), abs(ox + w), abs(oy + h)) + 2.0
            res = max(grid.resolution, 0.5)
            hf = dem_heightfield(args.dem, frame, size, res)
            heights, rollover = hf.heights, RolloverParams()
            print(f"[plan] DEM {args.dem}: {size:.0f} m about the datum at {res:g} m, heights "
                  f"{hf.z.min():+.1f}..{hf.z.max():+.1f} m from the origin's", flush=True)
        planner = Planner(grid, vehicle, params, heights, rollover)
        r = planner.plan(start, goal, args.budget)
    except (ConfigError, OSError) as exc:
        print(f"plan: {exc}", file=sys.stderr)
        return 2
    os.makedirs(args.out, exist_ok=True)
    info = summary(r, start, goal)
    info["map"] = os.path.abspath(args.map)
    info["map_summary"], info["map_warnings"] = grid.summary, list(grid.warnings)
    atomic_write(os.path.join(args.out, "plan.json"), json.dumps(info, indent=2) + "\n")
    if r.ok:
        write_csv(os.path.join(args.out, "path.csv"), r)
        print(f"[plan] {r.planner}: {r.length:.1f} m, cost {r.cost:.1f}, {r.cusps} cusp(s), first solution in "
              f"{1e3 * r.time_to_first:.0f} ms, {r.planning_time:.2f} s in all")
        if r.note:
            print(f"[plan] {r.note}")
    else:
        stale = os.path.join(args.out, "path.csv")
        if os.path.exists(stale):  # an earlier run's path must not pass for this one's
            os.remove(stale)
        print(f"[plan] {r.planner}: no path: {r.reason}", file=sys.stderr)
    plot(os.path.join(args.out, "plan.png"), planner, r, start, goal, os.path.basename(args.map))
    print(f"[plan] wrote {', '.join(n for n in ('path.csv', 'plan.png', 'plan.json') if os.path.exists(os.path.join(args.out, n)))} "
          f"in {args.out}")
    return 0 if r.ok else 1
