"""Benchmarks of the closed loop and of the smoother.

stack_rtf: the paper's figure eight (scenarios/figure_eight.yaml, its seed) closed loop,
the whole stack (simulator, adapters, PLC link, smoother, predictor, follower), run with
``rosrun quadrivio experiment`` at real-time factor 1, then at increasing factors. The
highest factor whose run completes with its tracking metrics (xte_rmse_m, xte_max_m)
within 10 % of the factor-1 run's, at an achieved factor of at least 95 % of the one asked
for, is ``stack_rtf`` (a stack that cannot keep up falls behind the simulated vehicle:
the follower acts on stale poses or aborts). Past that factor the simulator slows down for
the loop (sim_node ``~loop_hold``, ``~stale_slowdown``): the tracking holds and the
achieved factor falls short of the one asked for, so every factor is run and the highest
achieved factor with the tracking kept is ``stack_rtf_achieved``.

smoother_update_p99_ms, smoother_cpu_frac: the factor-1 run's sensor topics fed to the
smoother offline exactly as ``replay`` does (same order, 20 Hz updates on the bag's
clock); each update timed on the wall clock, and the CPU time of the whole replay over
the bag's duration: the share of one core the smoother needs at 20 Hz in real time.

Both record the machine's pace before and after (``pace_ms_before``/``_after``,
bench/common.py): a figure taken at a pace of 24 ms is not one taken at 10.

Writes bench/results/stack.json and bench/results/smoother.json.
"""
import os
import sys
import time

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # as launch/stack.launch runs the node (before numpy)
import numpy as np  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, experiment, machine, pace_ms, paces, write_result  # noqa: E402

FACTORS = (1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 8.0)
KEYS = ("xte_rmse_m", "xte_max_m")
SCENARIO = "figure_eight"


def run(rtf: float) -> dict:
    return experiment(SCENARIO, os.path.join(RESULTS, f".stack_rtf{rtf:g}"), rtf)


def stack_rtf() -> dict:
    runs = {}
    before = paces("before")  # the machine's speed swings 2.4 times within an hour: say how fast it was
    ref = run(1.0)
    runs[1.0] = ref
    print(f"[bench stack] factor 1: completed {ref['completed']}, " +
          ", ".join(f"{k} {ref.get(k)}" for k in KEYS), flush=True)
    if not ref["completed"]:
        raise SystemExit("[bench stack] the factor-1 run did not complete: no reference")
    best, best_achieved, sustained = 1.0, float(ref.get("rtf") or 1.0), True
    for f in FACTORS[1:]:
        m = run(f)
        runs[f] = m
        tracks = m["completed"] and all(m[k] is not None and m[k] <= 1.1 * ref[k] for k in KEYS)
        achieved = float(m.get("rtf") or 0.0)
        keeps_up = achieved >= 0.95 * f
        print(f"[bench stack] factor {f:g}: completed {m['completed']}, achieved rtf {achieved:.2f}, " +
              ", ".join(f"{k} {m.get(k)}" for k in KEYS) +
              (" ok" if tracks and keeps_up else " tracking kept, factor not sustained" if tracks
               else " -> beyond the stack"), flush=True)
        if tracks:
            best_achieved = max(best_achieved, achieved)
        sustained = sustained and tracks and keeps_up
        if sustained:
            best = f
    result = {"stack_rtf": best, "stack_rtf_achieved": best_achieved,
              "scenario": f"{SCENARIO} (its seed), factors tried {sorted(runs)}",
              "criterion": "completed, xte_rmse_m and xte_max_m within 10 % of the factor-1 run, achieved factor "
                           ">= 95 % of the one asked for (stack_rtf_achieved: the highest achieved factor of a run "
                           "that kept the tracking)",
              "machine": machine(), **before, **paces("after")}
    # Speed read against its limit (issue 28): the CPU per simulated second at factor 1, and at
    # factor 5 (the architecture's contract) the achieved factor over the CPU-bound one (cores /
    # CPU s per simulated s, while sim time ran: experiment's cpu_report)
    if runs[1.0].get("stack_cpu_s_per_sim_s") is not None:
        result["stack_cpu_s_per_sim_s_f1"] = runs[1.0]["stack_cpu_s_per_sim_s"]
    f_eff = 5.0 if 5.0 in runs else max(runs)
    if runs[f_eff].get("stack_efficiency") is not None:
        result["stack_efficiency"] = runs[f_eff]["stack_efficiency"]
        result["stack_efficiency_factor"] = f_eff
    for f, m in runs.items():
        for k in KEYS + ("loc_rmse_m", "rtf", "wall_s", "stack_cpu_s_per_sim_s", "stack_efficiency"):
            v = m.get(k)
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                result[f"f{f:g}_{k}"] = v
        result[f"f{f:g}_completed"] = 1.0 if m["completed"] else 0.0
    write_result("stack", result)
    return runs[1.0]


def smoother(bag_path: str) -> None:
    import rosbag

    from quadrivio_description.site import load_site
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_localization.ros import messages as M
    from quadrivio_localization.ros.replay_cli import Ticker, load_params
    from quadrivio_localization.smoother import Localizer
    from quadrivio_sim.paths import package_file

    params, _ = load_params([package_file("config", "mag_calibration.yaml")])
    loc = Localizer(params, load_vehicle(), load_site())
    feed = {"/gps/fix": M.add_gps, "/imu/data": M.add_imu, "/imu/mag": M.add_mag, "/vehicle/state": M.add_state}
    feed_s = 0.0
    with rosbag.Bag(bag_path) as bag:
        t_start, t_end = bag.get_start_time(), bag.get_end_time()
        msgs = list(bag.read_messages(topics=list(feed)))
    ticker = Ticker(loc, params.rate, t_start)  # replay's own schedule of updates
    pace_before = pace_ms()
    cpu0 = time.process_time()
    for topic, msg, t in msgs:
        for _ in ticker.until(t.to_sec()):
            pass
        w0 = time.perf_counter()
        feed[topic](loc, msg)
        feed_s += time.perf_counter() - w0
    cpu = time.process_time() - cpu0
    times = ticker.update_s
    ms = np.array(times) * 1e3
    duration = t_end - t_start
    result = {"smoother_update_p99_ms": float(np.percentile(ms, 99)),
              "smoother_update_p50_ms": float(np.percentile(ms, 50)),
              "smoother_update_max_ms": float(ms.max()),
              "smoother_cpu_frac": cpu / duration,
              "smoother_input_cpu_frac": feed_s / duration,
              "updates": len(times), "bag_seconds": duration, "keyframes": loc.counters.keyframes,
              "rate_hz": params.rate, "lag_s": params.lag,
              "scenario": f"{SCENARIO} closed loop at factor 1, its sensor topics replayed offline ({bag_path})",
              "machine": machine(), "pace_ms_before": pace_before, "pace_ms_after": pace_ms()}
    print(f"[bench smoother] update p50 {result['smoother_update_p50_ms']:.2f} ms, p99 "
          f"{result['smoother_update_p99_ms']:.2f} ms over {len(times)} updates; "
          f"{result['smoother_cpu_frac']:.3f} of a core at 20 Hz", flush=True)
    write_result("smoother", result)


def main():
    ref = stack_rtf()
    smoother(os.path.join(ref["out"], "run.bag"))


if __name__ == "__main__":
    main()
