"""``rosrun quadrivio analyze BAG --out DIR``: metrics.json and plots for any run's bag.

Simulated or real: what needs the ground truth (localization, prediction, GPS and
cross-track errors) is ``null`` in a real bag. A ``run_info.json`` next to the bag (written
by ``experiment``) supplies the scenario, the seed and the wall duration.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from typing import List, Optional

from quadrivio_config import ConfigError
from quadrivio_description.site import load_site
from quadrivio_description.vehicle import load_vehicle
from quadrivio_recordings.progress import BagProgress
from quadrivio_runtime.files import atomic_write

from .. import metrics
from ..plots import all_plots, format_metrics
from ..stop_views import write_views
from .bag import NEEDED_FOR, BagError, missing_topics, open_bag, read_run
from .stop_scenes import read_stop_scenes


def _run_info(bag: str) -> dict:
    """``run_info.json`` beside the bag ({} without one); a BagError naming it when unreadable."""
    info_path = os.path.join(os.path.dirname(os.path.abspath(bag)), "run_info.json")
    if not os.path.isfile(info_path):
        return {}
    try:
        with open(info_path) as fh:
            info = json.load(fh)
        if not isinstance(info, dict):
            raise ValueError(f"a JSON {type(info).__name__}, not an object")
    except (OSError, ValueError) as exc:  # json.JSONDecodeError is a ValueError
        raise BagError(f"{info_path} (the run's description beside the bag) is unreadable: {exc}; "
                       f"move it away to analyze the bag alone") from exc
    return info


def _guard_params(info: dict):
    """The guard's parameters the run used: its scenario's (when run_info.json names a
    readable one), else the package's guard.yaml."""
    from quadrivio_navigation.guard import GuardParams

    from ..closed_loop import _config
    from ..scenario import _defaults, load_scenario
    from quadrivio_description.paths import ros_package_path

    path = info.get("scenario_file")
    if isinstance(path, str) and os.path.isfile(path):
        try:
            return _config(GuardParams, "quadrivio_navigation", "guard.yaml", load_scenario(path), "guard")
        except (ConfigError, OSError, ValueError):
            pass  # the scenario has changed since: the defaults
    return _defaults(GuardParams, os.path.join(ros_package_path("quadrivio_navigation"), "config", "guard.yaml"))


def analyze(bag: str, out: str, site_file: str = "", vehicle_file: str = "", quiet: bool = False,
            map_file: str = "") -> dict:
    site, vehicle = load_site(site_file), load_vehicle(vehicle_file)
    imap = None
    if map_file:
        from quadrivio_recordings.ros import import_map

        imap = import_map.load(map_file)  # a ConfigError names the file and the key
    with open_bag(bag, BagError) as opened:  # its index read once
        missing = missing_topics(bag, imap, opened)
        if len(missing) == len(NEEDED_FOR):
            # nothing to compute: no metrics.json of nulls that reads like a result
            raise BagError(f"{bag} holds none of the topics the analysis reads: {'; '.join(missing)}. A recording "
                           f"made with other drivers' topics needs an import mapping (--map)")
        progress = BagProgress.of_bag("analyze", os.path.basename(bag), opened, quiet=quiet)
        run = read_run(bag, site, vehicle, imap, opened, progress=progress.update)
        info = _run_info(bag)
        guard = _guard_params(info)
        scenes, stops = read_stop_scenes(opened, bag, run, vehicle, [(sc.topic, sc.frame, sc.no_return)
                                                                 for sc in guard.scanners])
    progress.phase("read; computing the metrics")
    m = metrics.compute(run, info.get("scenario"), info.get("seed"), info.get("wall_duration_s"), vehicle)
    metrics.settle_completed(m, info.get("end"), info.get("outcome"))  # an experiment's run_info.json says them
    if info.get("stack_cpu_s") is not None:  # experiment measured its processes' CPU while sim time ran
        m.update(metrics.cpu_metrics(info.get("stack_cpu_s"), info.get("stack_cpu_sim_s"), info.get("stack_cpu_wall_s"),
                                     info.get("cpu_cores")))
    os.makedirs(out, exist_ok=True)
    atomic_write(os.path.join(out, "metrics.json"), json.dumps(m, indent=2) + "\n")
    title = f"{info.get('scenario') or os.path.basename(bag)}" + (f", seed {info['seed']}" if "seed" in info else "")
    progress.phase("metrics written; drawing the plots")
    made = all_plots(run, out, title)
    views = write_views(scenes, vehicle, guard.padding, out, title)
    if views and stops > len(views):
        views.append(f"(the first {len(views)} of {stops} stops)")
    made += views
    if not quiet:
        for w in run.warnings:
            print(f"[analyze] WARNING: {w}", file=sys.stderr)
    if not quiet and missing:
        print(f"[analyze] {bag} lacks {len(missing)} topic(s) the analysis uses; null or not plotted: "
              + "; ".join(missing))
    if not quiet:
        print("\n".join(["[analyze] metrics:"] + format_metrics(m)))
        print(f"[analyze] wrote {os.path.join(out, 'metrics.json')} and {', '.join(made)}")
    return m


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="analyze", description=__doc__.split("\n\n")[0])
    p.add_argument("bag")
    p.add_argument("--out", required=True, help="folder for metrics.json and the plots")
    p.add_argument("--site", default="", help="site YAML with the GPS datum (default: quadrivio_description's)")
    p.add_argument("--vehicle", default="", help="vehicle YAML (default: quadrivio_description's)")
    p.add_argument("--map", default="", metavar="YAML",
                   help="import mapping of a recording made with other drivers (its gps and state sections)")
    args = p.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    try:
        analyze(args.bag, args.out, args.site, args.vehicle, map_file=args.map)
    except (BagError, ConfigError) as exc:
        print(f"analyze: {exc}", file=sys.stderr)
        return 2
    return 0
