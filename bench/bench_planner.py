"""Benchmark: the two planners side by side on the same seeded start/goal pairs.

Maps (quadrivio_navigation.synthetic_maps.scattered, seeded): 100 m x 100 m at 0.2 m
with 60 round obstacles (0.5-3 m radius) and 8 buildings (3-14 m), and 500 m x 500 m at
1 m (an aerial map's resolution) with 1500 and 200. Pairs: uniformly drawn poses whose
footprint is free with 0.5 m to spare (beyond the planner's padding), at least 30 m
(150 m on the large map) apart, headings uniform.

For each pair, each planner runs with config/planner.yaml as the node uses it (lattice:
ARA* for 2 s; OMPL: RRTConnect, restarted and simplified for 2 s), timed one after the
other in this process; then, for the reference, each runs again with a 10 s budget (two
worker processes, timing not used). Keys:

* ``planner_lattice_p95_ms`` / ``planner_ompl_p95_ms``: time to the first solution, 95th
  percentile over the pairs (p50 and max too);
* ``planner_length_ratio``: path length over the shortest either planner found with 10 s,
  the mean over the pairs for each planner (``planner_lattice_length_ratio``,
  ``planner_ompl_length_ratio``), the worse of the two;
* success rates over the feasible pairs (those either planner solved with 10 s),
  collisions (poses of a returned path whose exact, unpadded footprint touches an
  occupied cell), peak memory of this process;
* the same on the large map with the suffix ``_500m``;
* ``pace_ms_before`` / ``_after``: the machine's pace around the run (bench/common.py): a
  time taken at a pace of 24 ms is not one taken at 10.

Writes bench/results/planner.json and planner_pairs.json (every pair's figures).
"""
import dataclasses
import math
import multiprocessing as mp
import os
import resource
import sys
import time

import numpy as np

from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.plan_cli import load_params
from quadrivio_navigation.planning import Planner
from quadrivio_navigation.synthetic_maps import scattered

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, pace_ms, write_result  # noqa: E402

MAPS = {
    "": dict(size=100.0, res=0.2, seed=21, rocks=60, buildings=8, pairs=50, min_dist=30.0),
    "_500m": dict(size=500.0, res=1.0, seed=22, rocks=1500, buildings=200, pairs=10, min_dist=150.0),
}
REFERENCE_BUDGET = 10.0  # [s]
CLEARANCE = 0.5  # [m] beyond the padding around start and goal footprints


def build(spec, params):
    grid = scattered(size=spec["size"], res=spec["res"], seed=spec["seed"], rocks=spec["rocks"],
                     buildings=spec["buildings"])
    return Planner(grid, load_vehicle(), params)


def draw_pairs(planner, spec):
    """Seeded start/goal pairs with some room around them."""
    roomy = Planner(planner.grid, planner.vehicle, dataclasses.replace(
        planner.p, cost=dataclasses.replace(planner.p.cost, padding=planner.p.cost.padding + CLEARANCE)))
    rng = np.random.default_rng(spec["seed"] + 1000)
    h = 0.5 * spec["size"] - 3.0
    pairs = []
    while len(pairs) < spec["pairs"]:
        s = (rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(-math.pi, math.pi))
        g = (rng.uniform(-h, h), rng.uniform(-h, h), rng.uniform(-math.pi, math.pi))
        if math.hypot(s[0] - g[0], s[1] - g[1]) >= spec["min_dist"] and not roomy.check_pose(s, "s") and \
                not roomy.check_pose(g, "g"):
            pairs.append((s, g))
    return pairs


def collisions(planner, poses) -> int:
    """Poses whose exact footprint (no padding) touches an occupied cell."""
    exact = Footprint.from_vehicle(planner.vehicle)
    return sum(1 for x, y, th in poses if planner.cost.collides(exact, x, y, th))


def run_pair(planner, s, g, kind, budget):
    r = planner.plan(s, g, budget, planner=kind)
    return {"ok": r.ok, "reason": r.reason, "first_ms": 1e3 * r.time_to_first if r.ok else None,
            "time_s": r.planning_time, "length_m": r.length if r.ok else None, "cost": r.cost if r.ok else None,
            "cusps": r.cusps if r.ok else None, "collisions": collisions(planner, r.poses) if r.ok else 0}


_WORKER = {}


def _reference(args):
    key, i, kind = args
    planner, pairs = _WORKER[key]
    s, g = pairs[i]
    return key, i, kind, run_pair(planner, s, g, kind, REFERENCE_BUDGET)


def main():
    params = load_params([])
    # the machine's speed swings 2.4 times within a day: a time read beside the pace (bench/common.py)
    result = {"machine": machine(), "pace_ms_before": pace_ms(), "reference_budget_s": REFERENCE_BUDGET,
              "budget_s": params.budget, "ompl_planner": params.ompl.planner, "start_goal_clearance_m": CLEARANCE}
    per_pair = {}
    for key, spec in MAPS.items():
        t = time.perf_counter()
        planner = build(spec, params)
        planner.lattice()
        planner.ompl()
        result[f"planner_map_build_s{key}"] = time.perf_counter() - t
        pairs = draw_pairs(planner, spec)
        _WORKER[key] = (planner, pairs)
        print(f"[bench] map{key or '_100m'}: {planner.grid.width} x {planner.grid.height} cells, {len(pairs)} pairs, "
              f"built in {result[f'planner_map_build_s{key}']:.1f} s", flush=True)
        rows = []
        for i, (s, g) in enumerate(pairs):
            row = {"start": s, "goal": g}
            for kind in ("lattice", "ompl"):
                row[kind] = run_pair(planner, s, g, kind, params.budget)
            rows.append(row)
            print(f"[bench]   pair {i + 1}/{len(pairs)}: lattice {fmt(row['lattice'])}, ompl {fmt(row['ompl'])}",
                  flush=True)
        per_pair[key or "_100m"] = rows
    # references: both planners with 10 s, two at a time (lengths only)
    jobs = [(key, i, kind) for key in MAPS for i in range(len(_WORKER[key][1])) for kind in ("lattice", "ompl")]
    print(f"[bench] references: {len(jobs)} plans of {REFERENCE_BUDGET:.0f} s in 2 processes", flush=True)
    with mp.get_context("fork").Pool(2) as pool:
        for n, (key, i, kind, ref) in enumerate(pool.imap_unordered(_reference, jobs), start=1):
            per_pair[key or "_100m"][i][f"{kind}_reference"] = ref
            if n % 10 == 0:
                print(f"[bench]   {n}/{len(jobs)} references", flush=True)
    for key in MAPS:
        result.update(summarise(per_pair[key or "_100m"], key))
    result["planner_peak_memory_mb"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    result["pace_ms_after"] = pace_ms()
    write_result("planner", result)
    write_result("planner_pairs", {"machine": result["machine"], "pairs": per_pair})
    for k in sorted(result):
        if k.startswith("planner_"):
            print(f"  {k:40s} {result[k]}")


def fmt(r):
    return (f"{r['first_ms']:.0f} ms to first, {r['length_m']:.1f} m" if r["ok"] else f"FAILED ({r['reason'][:50]})")


def summarise(rows, key):
    out = {}
    feasible = [r for r in rows if r["lattice_reference"]["ok"] or r["ompl_reference"]["ok"]]
    out[f"planner_pairs{key}"] = len(rows)
    out[f"planner_feasible_pairs{key}"] = len(feasible)
    ratios = {}
    for kind in ("lattice", "ompl"):
        firsts = [r[kind]["first_ms"] for r in feasible if r[kind]["ok"]]
        if firsts:
            out[f"planner_{kind}_p50_ms{key}"] = float(np.percentile(firsts, 50))
            out[f"planner_{kind}_p95_ms{key}"] = float(np.percentile(firsts, 95))
            out[f"planner_{kind}_max_ms{key}"] = float(np.max(firsts))
        out[f"planner_{kind}_success{key}"] = sum(r[kind]["ok"] for r in feasible) / max(1, len(feasible))
        out[f"planner_{kind}_collisions{key}"] = sum(r[kind]["collisions"] + r[f"{kind}_reference"]["collisions"]
                                                    for r in rows)
        rr = []
        for r in feasible:
            best = min(x["length_m"] for x in (r["lattice_reference"], r["ompl_reference"]) if x["ok"])
            if r[kind]["ok"]:
                rr.append(r[kind]["length_m"] / best)
        if rr:
            ratios[kind] = float(np.mean(rr))
            out[f"planner_{kind}_length_ratio{key}"] = ratios[kind]
            out[f"planner_{kind}_length_ratio_p95{key}"] = float(np.percentile(rr, 95))
        cusps = [r[kind]["cusps"] for r in feasible if r[kind]["ok"]]
        if cusps:
            out[f"planner_{kind}_cusps_mean{key}"] = float(np.mean(cusps))
    if ratios:
        out[f"planner_length_ratio{key}"] = max(ratios.values())
    return out


if __name__ == "__main__":
    main()
