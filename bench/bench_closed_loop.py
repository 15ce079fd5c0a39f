"""The closed loop in one process (quadrivio.closed_loop, issue 28). Writes
bench/results/closed_loop.json:

* ``inprocess_rtf``: one closed-loop figure eight (lasers, guard, follower on the estimate)
  in this process, simulated seconds over wall seconds (target >= 10 on one core);
  ``inprocess_sim_s_per_cpu_s``: the same over this process's CPU time (the figure the
  machine's load does not move); ``inprocess_cpu_share``: where that CPU goes (cProfile of
  a second run of 30 simulated seconds: the smoother, the simulator, the guard, ...);
  ``pace_ms_before``/``_after``: the machine's pace around that run (bench/common.py
  ``pace_ms``: the same fixed work each time; the machine's speed swings 30 % in minutes);
* ``campaign_cl_sim_s_per_wall_s``: ``campaign --closed-loop`` of the figure eight and the
  orchard, ``--seeds`` seeds each (default 2), 2 local workers: simulated seconds over the
  campaign's wall seconds (target >= 20), and the same campaign's runs' own figures;
  ``campaign_cl_cpu_limit``: its limit, were the two workers' cores busy with nothing but
  the runs (their simulated seconds over half their CPU seconds: no start-up, no plots).

``--seeds N``, ``--skip-campaign``.
"""
import argparse
import cProfile
import json
import os
import pstats
import subprocess
import sys
import tempfile
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # one core means one core (see launch/stack.launch)
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, paces, write_result  # noqa: E402

PARTS = {  # cProfile's cumulative time of these functions, each a share of the run's
    "smoother": "smoother.py:update", "simulator": "simulator.py:step",
    "guard": ("guard_native.py:decide", "guard.py:decide"),  # the roscpp core by default, or the Python one
    "scan handling": "closed_loop.py:on_scan", "follower": "follower.py:update", "predictor": "predictor.py:predicted",
    "planner": "planning.py:plan", "local layer": "local_layer.py:add_scan",
}


def one_run() -> dict:
    from quadrivio import closed_loop
    from quadrivio.scenario import load_scenario

    s = load_scenario("figure_eight")
    w0 = time.perf_counter()
    r = closed_loop.run(s, 0)
    wall = time.perf_counter() - w0
    return {"inprocess_rtf": r.sim_s / wall, "inprocess_sim_s_per_cpu_s": r.sim_s / r.cpu_s,
            "inprocess_sim_s": r.sim_s, "inprocess_wall_s": wall, "inprocess_cpu_s": r.cpu_s,
            "inprocess_outcome": r.outcome}


def profile() -> dict:
    from quadrivio import closed_loop
    from quadrivio.scenario import load_scenario

    pr = cProfile.Profile()
    pr.enable()
    closed_loop.run(load_scenario("figure_eight"), 0, max_duration=30.0)
    pr.disable()
    st = pstats.Stats(pr).stats
    total = max(ct for (_, _, _, ct, _) in st.values())
    out = {}
    for part, keys in PARTS.items():
        cum = 0.0
        for key in (keys,) if isinstance(keys, str) else keys:
            file, fn = key.split(":")
            cum += sum(ct for (f, _, name), (_, _, _, ct, _) in st.items() if f.endswith("/" + file) and name == fn)
        out[part] = round(cum / total, 3)
    return out


def campaign(seeds: int) -> dict:
    out = tempfile.mkdtemp(prefix="bench_cl_")
    cmd = ["rosrun", "quadrivio", "campaign", "figure_eight", "orchard", "--seeds", str(seeds), "--closed-loop",
           "--workers", "2", "--out", out]
    w0 = time.monotonic()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.monotonic() - w0
    if p.returncode not in (0, 1):
        raise SystemExit(f"campaign failed (exit {p.returncode}): {p.stdout[-2000:]} {p.stderr[-2000:]}")
    with open(os.path.join(out, "campaign.json")) as fh:
        c = json.load(fh)
    meta = c.get("meta", c)
    runs = c.get("runs", [])
    sim = sum(float(r.get("sim_s") or 0.0) for r in runs)
    cpu = sum(float(r.get("cpu_s") or 0.0) for r in runs)
    return {"campaign_cl_sim_s_per_wall_s": sim / wall, "campaign_cl_sim_s": sim, "campaign_cl_wall_s": wall,
            "campaign_cl_runs_cpu_s": cpu, "campaign_cl_cpu_limit": sim / (cpu / 2.0) if cpu > 0 else None,
            "campaign_cl_campaign_wall_s": meta.get("wall_s"), "campaign_cl_runs": len(runs),
            "campaign_cl_completed": sum(1 for r in runs if r.get("completed") == 1.0),
            "campaign_cl_folder": out}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=2)
    ap.add_argument("--skip-campaign", action="store_true")
    args = ap.parse_args()
    result = {"machine": machine(), "date": time.strftime("%Y-%m-%d %H:%M:%S")}
    print("[bench closed_loop] one figure eight in this process", flush=True)
    result.update(paces("before"))
    result.update(one_run())
    result.update(paces("after"))
    print(f"[bench closed_loop] inprocess_rtf {result['inprocess_rtf']:.2f} "
          f"({result['inprocess_sim_s_per_cpu_s']:.2f} simulated s per CPU s; the machine's pace "
          f"{result['pace_ms_before']:.1f} ms before, {result['pace_ms_after']:.1f} after)", flush=True)
    result["inprocess_cpu_share"] = profile()
    print(f"[bench closed_loop] CPU shares {result['inprocess_cpu_share']}", flush=True)
    if not args.skip_campaign:
        print(f"[bench closed_loop] campaign --closed-loop figure_eight orchard x {args.seeds} seeds, 2 workers",
              flush=True)
        result.update(campaign(args.seeds))
        print(f"[bench closed_loop] campaign_cl_sim_s_per_wall_s {result['campaign_cl_sim_s_per_wall_s']:.2f} "
              f"(the runs alone on two cores: {result['campaign_cl_cpu_limit'] or float('nan'):.2f})", flush=True)
    write_result("closed_loop", result)


if __name__ == "__main__":
    main()
