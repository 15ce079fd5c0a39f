"""``rosrun quadrivio campaign SCENARIOS... --seeds N --out DIR``: scenarios x seeds, in parallel.

Each run is either *offline* (default: :mod:`quadrivio.offline`, the simulator core, the
sensor models and the smoother in one process, the follower on the ground truth: every
estimator sees the same readings), *closed loop* (``--closed-loop``:
:mod:`quadrivio.closed_loop`, the whole stack in one process, the follower on the
estimate, as fast as a core goes; ``runs/<scenario>_s<seed>/`` holds its metrics.json, and
its plots if it is notable, see ``--run-plots``) or *closed loop through ROS* (``--closed-loop --ros``: ``experiment`` per run, the
ROS stack on its own master, for what only ROS can show). Runs are tasks on Dask distributed: a local cluster of ``--workers`` processes
by default, or the scheduler at ``--scheduler ADDRESS`` (``python3 -m distributed.cli.dask_scheduler``
on one machine, ``python3 -m distributed.cli.dask_worker ADDRESS`` on each of the others, all with
env.sh sourced: Debian's ``/usr/bin/dask-worker`` runs the system Python, without gtsam; see
docs/campaigns.md).

Written to ``DIR`` (each file complete or absent: written aside and renamed):

* ``runs/<scenario>_s<seed>.json`` -- one run's figures (and, offline, ``.npz`` with its
  error over time); a campaign run again into the same folder reuses finished runs of
  the same scenario file and seed, so an interrupted campaign resumes;
* ``campaign.csv``, ``campaign.md`` -- one row per scenario: mean and spread (standard
  deviation) over the seeds of every figure;
* ``campaign.json`` -- the table and every run;
* ``campaign.png`` -- the table as a picture: a panel per figure, a row per scenario, each
  seed a dot and the mean a bar;
* ``<scenario>_errors.png`` -- position error over time, one line per seed, the raw GPS's
  error behind it;
* ``<scenario>_tracks.png`` -- closed loop: every seed's true track on the scenario's map,
  with the actors, the guard's stops and the contacts (``runs/<scenario>_s<seed>.npz``
  holds what these plots draw).
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import io
import json
import math
import os
import subprocess
import sys
import time
from typing import Dict, List, Optional

import numpy as np

from quadrivio_config import ConfigError
from quadrivio_runtime.files import atomic_write

from .scenario import load_scenario

# Figures of a run that the table averages (key, header, unit)
COLUMNS = (("rmse_m", "RMSE", "m"), ("gps_rmse_m", "GPS RMSE", "m"), ("ratio_to_gps", "RMSE / GPS", ""),
           ("gps_drift_rms_m", "GPS drift alone", "m"), ("gps_oracle_rms_m", "oracle (perfect odometry)", "m"),
           ("max_error_m", "max error", "m"), ("heading_rmse_deg", "heading RMSE", "deg"),
           ("steer_offset_error_deg", "steering offset error", "deg"),
           ("wheel_scale_error_pct", "wheel scale error", "%"), ("outage_end_error_m", "error at outage end", "m"),
           ("outage_10s_error_m", "error 10 s after", "m"), ("dead_wheel_named_after_s", "fault named after", "s"),
           ("gps_not_used", "GPS fixes not used", ""), ("update_p99_ms", "update p99", "ms"),
           ("cpu_frac", "smoother CPU", ""),
           # closed-loop runs with obstacles and actors (OBSTACLES.md)
           ("completed", "completed", ""),
           ("xte_rmse_m", "cross-track RMSE", "m"), ("xte_est_rmse_m", "cross-track RMSE, estimated", "m"),
           ("collisions", "collisions", ""),
           ("min_clearance_m", "min clearance", "m"), ("protective_stops", "protective stops", ""),
           ("false_stops", "false stops", ""), ("anticipated_stops", "anticipated stops", ""),
           ("time_blocked_s", "time blocked", "s"))


SCHEDULER_TIMEOUT = 10.0  # [s] to connect to --scheduler
# What every run imports (PyBullet, GTSAM, the planner's native core): the local cluster's fork
# server imports them once as it starts, while this process still reads the scenarios, not each
# worker in its first run; a remote worker imports them as it starts (docs/campaigns.md).
WORKER_PRELOAD = ("quadrivio.campaign", "quadrivio_sim.simulator", "quadrivio_localization.smoother",
                  "quadrivio_navigation.planning")


class CampaignError(Exception):
    pass


def _digest(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.sha256(f.read()).hexdigest()[:16]


# ----------------------------------------------------------------- one run
def local_cluster(workers: int):
    """A Dask cluster of ``workers`` processes on this machine, one thread each, for runs.

    The runs are the parallelism: one BLAS thread per worker (numpy's OpenBLAS spins a thread
    per core after each call: twice a run's CPU for nothing, see launch/stack.launch). And no
    statistical profiler: Dask's samples each worker's stack every 10 ms for a dashboard that
    is not served here, a tenth of a closed-loop run's CPU (bench/HISTORY.md). The scheduler's
    HTTP server (its health and metrics routes: Dask binds one even without a dashboard) on a
    free loopback port: on Dask's default, 8787 on every interface, a second campaign on the
    machine warned "Port 8787 is already in use", and the first answered the network.

    The workers are forked by a fork server that imports Dask and what every run imports
    once (:data:`WORKER_PRELOAD`), not each started afresh to import them itself: 0.3-0.5 s
    less for a four-run campaign on this machine's two cores (bench/HISTORY.md). The server
    is a process of its own with no thread, so its forks are safe, where forking this
    process (Dask's threads) hung campaigns. The workers leave Ctrl-C to this process
    (:mod:`quadrivio.local_worker`), which closes them."""
    import multiprocessing
    import multiprocessing.forkserver

    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    # The workers' Dask loggers from warnings up, from their start: silence_logs comes later
    # than their preloads' INFO lines (what the worker's environment says, it reads at import).
    os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
    multiprocessing.get_context("forkserver").set_forkserver_preload(["distributed", *WORKER_PRELOAD])
    multiprocessing.forkserver.ensure_running()  # its imports while this process imports Dask's
    import dask
    import distributed.utils
    from distributed import LocalCluster

    # Dask would set its own list (and import every optional package it knows here first,
    # pandas among them) unless told that the fork server's list is set.
    distributed.utils._forkserver_preload_set = True
    with dask.config.set({"distributed.worker.profile.enabled": False,  # the workers start with it
                          "distributed.worker.multiprocessing-method": "forkserver"}):
        return LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address="127.0.0.1:0",
                            silence_logs=40, preload=[*WORKER_PRELOAD, "quadrivio.local_worker"])


def run_offline(scenario_path: str, seed: int, out_dir: str, settle: float) -> Dict:
    """One offline run (a Dask task: imports inside, returns plain data)."""
    from quadrivio import offline

    s = load_scenario(scenario_path)
    r = offline.run(s, seed, record_inputs=False)
    fig = offline.score(r, s, settle)
    fig = flatten(fig)
    err = offline.errors(r)
    a = r.antenna
    fixes = a[a[:, 7] >= 0] if len(a) else a
    buf = io.BytesIO()
    np.savez_compressed(buf, t=err[:, 0], error=err[:, 1], gps_t=fixes[:, 0],
                        gps_error=np.hypot(fixes[:, 3] - fixes[:, 1], fixes[:, 4] - fixes[:, 2]))
    base = os.path.join(out_dir, "runs", f"{s.name}_s{seed}")
    atomic_write(base + ".npz", buf.getvalue())
    return fig


def _write_series(out_dir: str, name: str, seed: int, run) -> None:
    """A closed-loop run's arrays for the campaign's plots (campaign_plots.run_series)."""
    from .campaign_plots import run_series

    buf = io.BytesIO()
    np.savez_compressed(buf, **run_series(run))
    atomic_write(os.path.join(out_dir, "runs", f"{name}_s{seed}.npz"), buf.getvalue())


def run_closed_loop(scenario_path: str, seed: int, out_dir: str, settle: float, rtf: Optional[float]) -> Dict:
    """One run through ``experiment`` (the whole stack on its own ROS master: ``--ros``)."""
    s = load_scenario(scenario_path)
    folder = os.path.join(out_dir, "runs", f"{s.name}_s{seed}")
    cmd = ["rosrun", "quadrivio", "experiment", scenario_path, "--seed", str(seed), "--out", folder]
    if rtf is not None:
        cmd += ["--rtf", str(rtf)]
    p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    metrics = os.path.join(folder, "metrics.json")
    # exit 1: the run ran but did not complete (its figures count, marked so); else a failure
    if p.returncode not in (0, 1) or not os.path.exists(metrics):
        tail = " | ".join(p.stdout.strip().splitlines()[-3:])
        raise CampaignError(f"experiment {s.name} seed {seed} failed (exit {p.returncode}): {tail}")
    with open(metrics) as f:
        m = json.load(f)
    try:  # how the run ended (experiment's run_info.json): said for the runs that did not complete
        with open(os.path.join(folder, "run_info.json")) as f:
            m.setdefault("outcome", json.load(f).get("outcome"))
    except (OSError, ValueError, AttributeError):
        pass
    fig = _closed_loop_figures(s, seed, m, p.returncode == 0)
    try:  # the bag experiment analysed, read again for the campaign's plots
        from quadrivio_description.site import load_site
        from quadrivio_description.vehicle import load_vehicle

        from .ros.bag import read_run

        _write_series(out_dir, s.name, seed, read_run(os.path.join(folder, "run.bag"), load_site(""), load_vehicle("")))
    except Exception as exc:  # the run's figures stand without its plots; campaign.json says why
        fig["plot_error"] = f"{type(exc).__name__}: {exc}"
    return fig


def notable(fig: Dict) -> bool:
    """A closed-loop run worth its own plots: it did not complete, touched a body, or the
    guard stopped it for nothing."""
    return (fig.get("end") != "completed" or fig.get("completed") == 0.0  # its run, or its path, unfinished
            or bool(fig.get("collisions")) or bool(fig.get("false_stops")))


def run_in_process(scenario_path: str, seed: int, out_dir: str, settle: float, run_plots: str = "notable") -> Dict:
    """One closed-loop run in this process (:mod:`quadrivio.closed_loop`; a Dask task). Its
    folder gets its plots as ``run_plots`` says: ``all``, ``notable`` runs only
    (:func:`notable`), or ``none`` (they cost a quarter of a figure eight's CPU)."""
    from . import closed_loop

    s = load_scenario(scenario_path)
    folder = os.path.join(out_dir, "runs", f"{s.name}_s{seed}")
    r = closed_loop.run(s, seed)
    m = closed_loop.write_run(r, s, seed, folder, plots=False)
    _write_series(out_dir, s.name, seed, r.run)
    done = m.get("completed")
    if done is None or s.run.end == "duration":
        done = r.outcome == "completed"
    fig = _closed_loop_figures(s, seed, m, bool(done))
    fig.update(sim_s=r.sim_s, cpu_s=r.cpu_s)
    if run_plots == "all" or (run_plots == "notable" and notable(fig)):
        closed_loop.plot_run(r, s, seed, folder)
    return fig


def _closed_loop_figures(s, seed: int, m: Dict, completed: bool) -> Dict:
    """A closed-loop run's figures for the table, from its metrics.json."""
    return {"scenario": s.name, "seed": seed, "end": "completed" if completed else "not completed",
            "outcome": m.get("outcome"),
            "rmse_m": m.get("loc_rmse_after_10s_m", m.get("loc_rmse_m")), "gps_rmse_m": m.get("gps_rmse_m"),
            "max_error_m": m.get("loc_max_m"), "heading_rmse_deg": m.get("loc_heading_rmse_deg"),
            "wall_s": m.get("wall_duration_s"), "sim_s": m.get("sim_duration_s"), "xte_rmse_m": m.get("xte_rmse_m"),
            "xte_est_rmse_m": m.get("xte_est_rmse_m"),
            "completed": None if m.get("completed") is None else float(bool(m.get("completed"))),
            **{k: m.get(k) for k in ("collisions", "min_clearance_m", "protective_stops", "false_stops",
                                     "anticipated_stops", "time_blocked_s", "goal_position_error_m")}}


def flatten(fig: Dict) -> Dict:
    """A run's figures (offline.score) as flat keys: the first outage's, GPS fixes not used by reason."""
    out = {k: v for k, v in fig.items() if k not in ("counters", "outages")}
    if fig.get("outages"):
        o = fig["outages"][0]
        out["outage_end_error_m"], out["outage_10s_error_m"] = o["error_at_end_m"], o["error_10s_after_m"]
    if fig.get("gps_rmse_m") and fig.get("rmse_m") is not None:
        out["ratio_to_gps"] = fig["rmse_m"] / fig["gps_rmse_m"]
    counts = (fig.get("counters") or {}).get("gps_not_used") or {}
    out["gps_not_used"] = float(sum(counts.values())) if counts else 0.0
    out["gps_not_used_by_reason"] = counts
    return out


# ------------------------------------------------------------------- table
def table(runs: List[Dict], order: List[str]) -> List[Dict]:
    rows = []
    for name in order:
        rs = [r for r in runs if r["scenario"] == name]
        row: Dict[str, object] = {"scenario": name, "seeds": len(rs)}
        for key, _, _ in COLUMNS:
            vals = np.array([r[key] for r in rs if isinstance(r.get(key), (int, float)) and r[key] is not None
                             and math.isfinite(r[key])], float)
            row[key] = float(vals.mean()) if len(vals) else None
            row[key + "_sd"] = float(vals.std(ddof=1)) if len(vals) > 1 else None
        rows.append(row)
    return rows


def _fmt(v: Optional[float], sd: Optional[float]) -> str:
    if v is None:
        return ""
    digits = 3 if abs(v) < 10 else 1
    return f"{v:.{digits}f}" + (f" ± {sd:.{digits}f}" if sd is not None else "")


def write_tables(out: str, rows: List[Dict], runs: List[Dict], meta: Dict) -> None:
    used = [c for c in COLUMNS if any(r.get(c[0]) is not None for r in rows)]
    sio = io.StringIO()
    w = csv.writer(sio)
    w.writerow(["scenario", "seeds"] + [h for k, _, _ in used for h in (k, k + "_sd")])
    for r in rows:
        w.writerow([r["scenario"], r["seeds"]] + [("" if r.get(h) is None else f"{r[h]:.6g}")
                                                 for k, _, _ in used for h in (k, k + "_sd")])
    atomic_write(os.path.join(out, "campaign.csv"), sio.getvalue().encode())
    md = [f"# Campaign: {', '.join(r['scenario'] for r in rows)} ({meta['mode']}, seeds {meta['seeds']})", "",
          "Mean ± standard deviation over the seeds.", "",
          "| scenario | seeds | " + " | ".join(f"{h} [{u}]" if u else h for _, h, u in used) + " |",
          "|---|---|" + "---|" * len(used)]
    for r in rows:
        md.append(f"| {r['scenario']} | {r['seeds']} | " +
                  " | ".join(_fmt(r.get(k), r.get(k + "_sd")) for k, _, _ in used) + " |")
    md += _not_completed(runs)
    atomic_write(os.path.join(out, "campaign.md"), ("\n".join(md) + "\n").encode())
    atomic_write(os.path.join(out, "campaign.json"),
                  json.dumps({"meta": meta, "table": rows, "runs": runs}, indent=1, default=float).encode())


def _progress_end(fig: Dict) -> str:
    """How a closed-loop run ended, for its progress line, in the table's words: a run that
    ends at its time limit (``run: end: duration``) ran to its end whether or not its path
    completed (the dog that stays in the lane), so both are said; contacts and stops too."""
    if fig.get("end") != "completed":
        words = "not completed"
    elif fig.get("completed") == 0.0:
        words = "ran to its end, path not completed"
    else:
        words = "completed"
    for key, name in (("collisions", "contact"), ("protective_stops", "protective stop"),
                      ("false_stops", "false stop")):
        n = fig.get(key)
        if n:
            words += f", {int(n)} {name}{'s' if n != 1 else ''}"
    return words


def _not_completed(runs: List[Dict], most: int = 20) -> List[str]:
    """campaign.md's lines naming each closed-loop run that did not complete and how it
    ended (its outcome: the planner's reason, the follower's, a time limit), in table order;
    the first ``most``, the rest counted (campaign.json has them all)."""
    failed = [r for r in runs if r.get("outcome") and r.get("end") != "completed"]
    if not failed:
        return []
    lines = ["", "Runs that did not complete:", ""]
    lines += [f"- {r['scenario']} seed {r['seed']}: {r['outcome']}" for r in failed[:most]]
    if len(failed) > most:
        lines.append(f"- and {len(failed) - most} more (campaign.json, `runs`)")
    return lines


def _series(out: str, name: str, seeds: List[int]) -> List:
    """(seed, arrays) of each of a scenario's runs that left ``runs/<name>_s<seed>.npz``."""
    series = []
    for seed in seeds:
        path = os.path.join(out, "runs", f"{name}_s{seed}.npz")
        if os.path.exists(path):
            with np.load(path) as d:
                series.append((seed, {k: d[k] for k in d.files}))
    return series


def scenario_plot_jobs(out: str, s, seeds: List[int]) -> List:
    """One scenario's plots (its errors, and its tracks on its map) as (file name, function,
    arguments), :func:`plot_jobs`' way; their inputs are its runs' files, read here."""
    from . import campaign_plots
    from .scenario import map_file

    series = _series(out, s.name, seeds)
    jobs = [(f"{s.name}_errors.png", campaign_plots.errors, (s.name, series))]
    grid, file = None, map_file(s)
    if file:
        from quadrivio_navigation.maps import load_map

        grid = load_map(file)
    spec = s.data.get("path") or {}
    goal = spec.get("goal") if isinstance(spec, dict) and spec.get("kind") == "goal" else None
    jobs.append((f"{s.name}_tracks.png", campaign_plots.tracks, (s.name, series, grid, goal)))
    return jobs


def plot_jobs(out: str, scenarios, seeds: List[int], rows: List[Dict], runs: List[Dict], meta: Dict,
              early: Optional[Dict[str, List]] = None) -> List:
    """The campaign's plots as ((file name, function, arguments), future or None), in the
    order of the files: each function is pure (campaign_plots) and returns the PNG's bytes or
    None, so that a cluster's workers can draw them side by side; their inputs are read here,
    where the runs' files are. ``early``: a scenario's jobs with their futures, submitted
    before (:func:`_run_jobs`)."""
    from . import campaign_plots

    early = early or {}
    jobs = [(("campaign.png", campaign_plots.summary,
              (rows, runs, COLUMNS, f"{meta['mode']} campaign, seeds {meta['seeds']}")), None)]
    for s in scenarios:
        jobs += early[s.name] if s.name in early else [(job, None) for job in scenario_plot_jobs(out, s, seeds)]
    return jobs


def write_plots(out: str, scenarios, seeds: List[int], rows: List[Dict], runs: List[Dict], meta: Dict,
                client=None, early: Optional[Dict[str, List]] = None) -> List[str]:
    """campaign.png (the table), and per scenario its errors and, closed loop, its tracks on
    its map; the names of the files written. With a ``client`` (the campaign's
    :class:`Plotter`, or Dask's) it draws them (the table's plot is 0.3 s of CPU, a
    scenario's 0.15 s, matplotlib's import 0.3 s); without one, or if that fails, this
    process's own thread does. ``early``: per scenario, its
    jobs (:func:`scenario_plot_jobs`) with the futures of those submitted as its last run
    ended, while the other runs went on (:func:`_run_jobs`)."""
    jobs = plot_jobs(out, scenarios, seeds, rows, runs, meta, early)
    pngs = None
    if client is not None:
        try:
            futures = [fut if fut is not None else client.submit(fn, *args, pure=False)
                       for (_, fn, args), fut in jobs]
            pngs = client.gather(futures)
        except Exception as exc:  # a worker lost, say: draw them here
            _log(f"the plots' tasks failed ({type(exc).__name__}: {exc}); drawing them here")
    if pngs is None:
        pngs = [fn(*args) for (_, fn, args), _ in jobs]
    written = []
    for ((name, _, _), _), png in zip(jobs, pngs):
        if png is not None:
            atomic_write(os.path.join(out, name), png)
            written.append(name)
    return written


class Plotter:
    """One thread of this process drawing the campaign's plots, a client for
    :func:`write_plots` (``submit``, ``gather``): :meth:`start` has it import matplotlib once
    the runs are submitted (imported before, it held the interpreter while four runs were
    submitted, 0.25 s for what takes 0.02), and a scenario's plots are drawn as its last run
    ends, while the workers run the others; at the end only the table's plot and the last
    scenario's are left, drawn while the cluster closes. On this machine's two cores that
    made a four-run campaign 0.3-0.4 s shorter than the workers drawing everything once the
    runs were done (bench/HISTORY.md). One thread: matplotlib's figures are not for threads
    side by side."""

    def __init__(self) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(1, thread_name_prefix="campaign-plots")

    def start(self) -> None:
        """matplotlib's import, once, while the runs go (a plot imports it anyway)."""
        from . import campaign_plots

        self._pool.submit(campaign_plots._plt)

    def submit(self, fn, *args, pure: bool = False):
        return self._pool.submit(fn, *args)

    @staticmethod
    def gather(futures) -> List:
        return [f.result() for f in futures]

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)


# ------------------------------------------------------------------- main
def parse(argv):
    p = argparse.ArgumentParser(prog="campaign", description=__doc__.split("\n\n")[0])
    p.add_argument("scenarios", nargs="+", help="names from quadrivio/scenarios/ or paths to scenario YAML files")
    p.add_argument("--seeds", type=int, default=3, help="seeds per scenario: 0 .. N-1 (default 3)")
    p.add_argument("--first-seed", type=int, default=0, help="first seed (default 0)")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--closed-loop", action="store_true",
                   help="closed loop: the whole stack in one process per run (quadrivio.closed_loop)")
    p.add_argument("--ros", action="store_true",
                   help="with --closed-loop: each run through experiment instead (the ROS stack, a master each)")
    p.add_argument("--rtf", type=float, default=None, help="--closed-loop --ros: real-time factor (default: the "
                                                             "scenario's)")
    p.add_argument("--workers", type=int, default=None,
                   help="local cluster processes (default: CPU count; --ros: one per two cores, see docs/campaigns.md)")
    p.add_argument("--scheduler", default=None, help="address of a Dask scheduler instead of a local cluster")
    p.add_argument("--settle", type=float, default=20.0, help="[s] error statistics start here (default 20)")
    p.add_argument("--run-plots", choices=("notable", "all", "none"), default=None,
                   help="--closed-loop: which runs get their own plots in runs/<scenario>_s<seed>/: notable (default: "
                        "not completed, a contact or a false stop), all, or none; the campaign's own plots show "
                        "every run (--ros: experiment plots every run)")
    args = p.parse_args(argv)
    if args.seeds < 1 or args.first_seed < 0:
        p.error("--seeds must be at least 1 and --first-seed non-negative")
    if args.workers is not None and args.workers < 1:
        p.error("--workers must be at least 1")
    if args.settle < 0 or not math.isfinite(args.settle):
        p.error("--settle must be a non-negative number of seconds")
    if (args.ros or args.rtf is not None) and not args.closed_loop:
        p.error("--ros and --rtf go with --closed-loop")
    if args.rtf is not None and not args.ros:
        p.error("--rtf is the ROS stack's real-time factor: it goes with --closed-loop --ros (in one process a run "
                "goes as fast as its core)")
    if args.rtf is not None and not (0.0 <= args.rtf <= 100.0):
        p.error("--rtf must be within [0, 100]")
    if args.run_plots is not None and (args.ros or not args.closed_loop):
        p.error("--run-plots goes with --closed-loop in one process (offline runs have no plots of their own; "
                "--ros runs are experiments, each plotted)")
    args.run_plots = args.run_plots or "notable"
    return args


def _log(text: str) -> None:
    print(f"[campaign {time.strftime('%H:%M:%S')}] {text}", flush=True)


def _run_jobs(client, jobs, args, mode: str, runs: List[Dict], total: int, failures: List[str],
              wall0: float, scenario_done=None, submitted=None) -> float:
    """The runs of ``jobs`` ((scenario, seed, digest)) as tasks of ``client``; each finished
    run is written to ``runs/`` and appended to ``runs``, each failed one to ``failures``;
    progress in seconds since ``wall0`` (monotonic); ``submitted()`` once every run is
    submitted, ``scenario_done(scenario)`` as the last of a scenario's runs ends. The
    simulated seconds of the runs made."""
    from distributed import as_completed

    new_sim = 0.0
    futures = {}
    left: Dict[str, int] = {}
    for s, _, _ in jobs:
        left[s.name] = left.get(s.name, 0) + 1
    for s, seed, digest in jobs:
        if args.closed_loop and not args.ros:
            fut = client.submit(run_in_process, s.path, seed, os.path.abspath(args.out), args.settle,
                                args.run_plots, pure=False)
        elif args.closed_loop:
            fut = client.submit(run_closed_loop, s.path, seed, os.path.abspath(args.out), args.settle,
                                args.rtf, pure=False)
        else:
            fut = client.submit(run_offline, s.path, seed, os.path.abspath(args.out), args.settle, pure=False)
        futures[fut] = (s, seed, digest)
    if submitted is not None:
        submitted()
    for fut in as_completed(futures):
        s, seed, digest = futures[fut]
        left[s.name] -= 1
        if left[s.name] == 0 and scenario_done is not None:
            scenario_done(s)
        try:
            fig = fut.result()
        except Exception as exc:  # one failed run is reported; the others go on
            failures.append(f"{s.name} seed {seed}: {exc}")
            _log(f"FAILED {s.name} seed {seed}: {exc}")
            continue
        fig.update(scenario_digest=digest, mode=mode, scenario_file=s.path)
        atomic_write(os.path.join(args.out, "runs", f"{s.name}_s{seed}.json"),
                      json.dumps(fig, indent=1, default=float).encode())
        runs.append(fig)
        new_sim += float(fig.get("sim_s") or 0.0)
        elapsed = time.monotonic() - wall0
        gps = fig.get("gps_rmse_m")
        rmse = fig.get("rmse_m")
        _log(f"{len(runs)}/{total} {s.name} seed {seed}: "
             + (f"RMSE {rmse:.3f} m" if rmse is not None else "no estimate")
             + (f" (raw GPS {gps:.3f} m)" if gps else "")
             + (f", {_progress_end(fig)}" if args.closed_loop else "") + f", {elapsed:.0f} s elapsed")
    return new_sim


# Cores one free-running ROS stack wants: its nodes about half a core per simulated second at
# factor 1, and its planner a whole one while it searches on a wall-clock budget. Fewer, and a
# run's outcome depends on the campaign's own load (docs/campaigns.md has the measurement).
ROS_CORES_PER_STACK = 2


def default_workers(ros: bool) -> int:
    """Local workers by default: a core each in one process; with ``--ros``, a ROS stack per
    ``ROS_CORES_PER_STACK`` cores (at least one)."""
    cores = os.cpu_count() or 1
    return max(1, cores // ROS_CORES_PER_STACK) if ros else cores


def _start_cluster(args):
    """A local cluster of ``--workers`` processes (at most one per possible run), started in a
    thread: its workers start (a third of a second, about a core's worth of imports) while this
    process reads and checks the scenarios (a quarter of a second of the other core); the
    future's result is the cluster. None with ``--scheduler``."""
    if args.scheduler:
        return None
    from concurrent.futures import ThreadPoolExecutor

    workers = min(args.workers or default_workers(args.ros), len(args.scenarios) * args.seeds)
    cores = os.cpu_count() or 1
    if args.ros and workers > 1 and workers * ROS_CORES_PER_STACK > cores:
        _log(f"{workers} ROS stacks on {cores} cores: each wants {ROS_CORES_PER_STACK} (a core's searches for "
             f"the planner on its wall-clock budget beside the nodes' own load), so replans may time out and the guard "
             f"stop the vehicle where a stack alone would not (docs/campaigns.md)")
    pool = ThreadPoolExecutor(1, thread_name_prefix="campaign-cluster")
    starting = pool.submit(local_cluster, workers)
    pool.shutdown(wait=False)  # the thread ends with its one task
    return starting


def _close_in_background(client, cluster, starting):
    """A thread closing ``client`` and ``cluster`` (or the cluster still ``starting``, not
    used), started; join it."""
    import threading

    def close() -> None:
        try:
            if client is not None:
                client.close()
            if cluster is not None:
                cluster.close()
            else:
                _close_started(starting)
        except Exception as exc:  # the campaign's files are written all the same
            _log(f"closing the cluster: {type(exc).__name__}: {exc}")

    thread = threading.Thread(target=close, name="campaign-close")
    thread.start()
    return thread


def _close_started(starting) -> None:
    """Close the cluster of :func:`_start_cluster` once it has started (or failed to)."""
    if starting is None:
        return
    try:
        starting.result().close()
    except Exception:  # it never started: nothing to close
        pass


def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    starting = _start_cluster(args)
    try:
        scenarios = [load_scenario(n) for n in args.scenarios]
    except ConfigError as exc:
        print(f"campaign: {exc}; nothing run", file=sys.stderr)
        _close_started(starting)
        return 2
    names = [s.name for s in scenarios]
    if len(set(names)) != len(names):
        print(f"campaign: a scenario is named twice ({', '.join(names)}); nothing run", file=sys.stderr)
        _close_started(starting)
        return 2
    os.makedirs(os.path.join(args.out, "runs"), exist_ok=True)
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    mode = ("closed loop (ROS)" if args.ros else "closed loop") if args.closed_loop else "offline"
    jobs, runs = [], []
    for s in scenarios:
        digest = _digest(s.path)
        for seed in seeds:
            done = os.path.join(args.out, "runs", f"{s.name}_s{seed}.json")
            if os.path.exists(done):
                try:
                    with open(done) as f:
                        old = json.load(f)
                    if old.get("scenario_digest") == digest and old.get("mode") == mode:
                        runs.append(old)
                        continue
                except (OSError, ValueError):
                    pass  # unreadable: run it again
            jobs.append((s, seed, digest))
    total = len(jobs) + len(runs)
    _log(f"{len(scenarios)} scenario(s) x {len(seeds)} seed(s), {mode}: {len(jobs)} to run"
         + (f", {len(runs)} already done in {args.out}" if runs else ""))
    failures = []
    client = cluster = plotter = closing = None
    try:
        if jobs and starting is not None:
            from distributed import Client

            cluster = starting.result()
            client = Client(cluster)
        elif jobs:
            from distributed import Client

            try:
                client = Client(args.scheduler, timeout=SCHEDULER_TIMEOUT)
            except (OSError, TimeoutError) as exc:
                print(f"campaign: cannot reach the Dask scheduler at {args.scheduler} within "
                      f"{SCHEDULER_TIMEOUT:g} s ({exc}); nothing run", file=sys.stderr)
                return 2
        plotter = Plotter()
        early: Dict[str, List] = {}  # a scenario's plots, drawn while the other scenarios' runs go on

        def scenario_done(s) -> None:
            try:
                early[s.name] = [(job, plotter.submit(job[1], *job[2])) for job in scenario_plot_jobs(args.out, s, seeds)]
            except Exception as exc:  # its runs' files unreadable, say: drawn (or reported) at the end
                _log(f"{s.name}'s plots wait for the end ({type(exc).__name__}: {exc})")

        if jobs:
            wall0 = time.monotonic()
            new_sim = _run_jobs(client, jobs, args, mode, runs, total, failures, wall0, scenario_done, plotter.start)
        runs.sort(key=lambda r: (names.index(r["scenario"]), r["seed"]))
        rows = table(runs, names)
        meta = {"mode": mode, "seeds": seeds, "scenarios": {s.name: s.path for s in scenarios},
                "settle_s": args.settle, "failures": failures}
        if jobs:
            wall = time.monotonic() - wall0
            meta.update(wall_s=wall, sim_s=new_sim, sim_s_per_wall_s=new_sim / wall if wall > 0 else None)
            if args.closed_loop and new_sim:
                _log(f"{new_sim:.0f} simulated s in {wall:.0f} wall s: {new_sim / wall:.1f} simulated s per wall s")
        write_tables(args.out, rows, runs, meta)
        # the cluster closes (a third of a second) while the last plots are drawn
        closing = _close_in_background(client, cluster, starting)
        client = cluster = starting = None
        plots = write_plots(args.out, scenarios, seeds, rows, runs, meta, client=plotter, early=early)
    except KeyboardInterrupt:
        _log("interrupted: the finished runs are kept; run the same command to resume")
        return 130
    finally:
        if plotter is not None:
            plotter.close()
        if client is not None:
            client.close()
        if cluster is not None:
            cluster.close()
        elif starting is not None:  # not used, or interrupted before it was
            _close_started(starting)
        if closing is not None:
            closing.join()
    _log(f"wrote {os.path.join(args.out, 'campaign.md')} (and .csv, .json" +
         (f"; plots {', '.join(plots)}" if plots else "") + ")")
    with open(os.path.join(args.out, "campaign.md")) as f:
        print(f.read())
    if failures:
        print(f"campaign: {len(failures)} run(s) failed: " + "; ".join(failures), file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
