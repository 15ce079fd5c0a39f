"""Benchmark of lockstep (``experiment --lockstep``): how fast the closed loop runs when
the simulator waits for it every tick, and that it repeats.

The paper's figure eight (scenarios/figure_eight.yaml, its seed), the whole stack:

* free-running at real-time factor 1 (the reference: what the stack does live);
* lockstep as fast as the loop goes (``--rtf 0``), twice: ``lockstep_rtf`` is the factor
  it achieved (sim time over wall time, from metrics.json), ``lockstep_repeats`` whether
  the two bags are the same message for message (``compare_runs --prefix``: experiment
  stops the run when it sees the follower done, on the wall clock, so the runs end a few
  ticks apart);
* lockstep at factor 1: the same bag again (``lockstep_same_at_rtf1``): what a run does
  in lockstep does not depend on how fast it went;
* ``lockstep_cpu_s_per_sim_s``: the whole stack's CPU per simulated second in lockstep, and
  ``lockstep_cpu_limit_rtf``, the cores over it: the factor the loop could reach on this
  machine were it never waiting for a message (lockstep_rtf over it: how much it waits).

Tracking and localization of each run are recorded next to the free-running ones, and
``stack_rtf`` from bench/results/stack.json when bench_stack ran (free-running, the
highest factor that still tracks): the two factors side by side.

Writes bench/results/lockstep.json.
"""
import json
import os
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, experiment, machine, paces, write_result  # noqa: E402

SCENARIO = "figure_eight"
KEYS = ("completed", "rtf", "sim_duration_s", "xte_rmse_m", "xte_max_m", "loc_rmse_m", "pred_rmse_m",
        "stack_cpu_s_per_sim_s", "stack_efficiency")


def run(name: str, rtf: float, lockstep: bool) -> dict:
    m = experiment(SCENARIO, os.path.join(RESULTS, f".lockstep_{name}"), rtf, *(["--lockstep"] if lockstep else []))
    if "rtf" not in m:
        return m
    wall = m["wall_s"]
    print(f"[bench lockstep] {name}: completed {m['completed']}, achieved factor {m.get('rtf'):.2f}, "
          f"xte {m.get('xte_rmse_m')}, loc {m.get('loc_rmse_m')} ({wall:.0f} s wall)", flush=True)
    return m


def same(a: dict, b: dict) -> bool:
    # --prefix: experiment stops a path_done run when it sees the follower done, on the wall
    # clock: the two runs are cut a few ticks apart
    r = subprocess.run(["rosrun", "quadrivio", "compare_runs", "--prefix", os.path.join(a["out"], "run.bag"),
                        os.path.join(b["out"], "run.bag")], capture_output=True, text=True)
    print(f"[bench lockstep] {r.stdout.strip()}", flush=True)
    return r.returncode == 0


def main():
    before = paces("before")  # the machine's speed swings 2.4 times within an hour
    runs = {"free_f1": run("free_f1", 1.0, False), "lockstep_a": run("lockstep_a", 0.0, True),
            "lockstep_b": run("lockstep_b", 0.0, True), "lockstep_f1": run("lockstep_f1", 1.0, True)}
    a, b, f1 = runs["lockstep_a"], runs["lockstep_b"], runs["lockstep_f1"]
    ok = a.get("completed") and b.get("completed")
    result = {"scenario": f"{SCENARIO} (its seed)", "machine": machine(),
              "lockstep_rtf": min(a.get("rtf") or 0.0, b.get("rtf") or 0.0),
              "lockstep_repeats": 1.0 if ok and same(a, b) else 0.0,
              "lockstep_same_at_rtf1": 1.0 if ok and f1.get("completed") and same(a, f1) else 0.0,
              **before, **paces("after")}
    # Read against its limit: the cores over the CPU the stack spends per simulated second
    # in lockstep (the factor it could reach were the loop never waiting on a message)
    cpu = [m.get("stack_cpu_s_per_sim_s") for m in (a, b) if m.get("stack_cpu_s_per_sim_s")]
    if cpu:
        result["lockstep_cpu_s_per_sim_s"] = min(cpu)
        result["lockstep_cpu_limit_rtf"] = (os.cpu_count() or 1) / min(cpu)
    stack = os.path.join(RESULTS, "stack.json")
    if os.path.isfile(stack):
        with open(stack) as fh:
            result["free_stack_rtf"] = json.load(fh).get("stack_rtf")
    for name, m in runs.items():
        for k in KEYS + ("wall_s",):
            v = m.get(k)
            if isinstance(v, bool):
                v = 1.0 if v else 0.0
            if isinstance(v, (int, float)):
                result[f"{name}_{k}"] = v
    write_result("lockstep", result)
    if not result["lockstep_repeats"]:
        raise SystemExit("[bench lockstep] the two lockstep runs differ")


if __name__ == "__main__":
    main()
