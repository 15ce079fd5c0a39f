"""Endurance (issue 11): ten simulated minutes of the closed loop at the highest factor.

The paper's figure eight (scenarios/figure_eight.yaml: its seed, its GPS outages and
multipath) driven lap after lap for ``ENDURANCE_SIM_S`` simulated seconds (600) with
``rosrun quadrivio experiment --rtf F``, F being ``stack_rtf`` from the last
bench/results/stack.json (``ENDURANCE_RTF`` overrides it; 4 without either). Two checks:

* **rates** (what rostest's hztest checks, over the whole run): every contract topic of
  the bag (ARCHITECTURE.md), counted per minute of simulated time, must keep its
  configured rate within ``RATE_TOL`` in every minute, and no gap between two messages
  may exceed ``GAP_PERIODS`` of its periods. The expected rates are read from the
  config files the stack itself reads (sim.yaml, localization.yaml, predictor.yaml,
  follower.yaml), not written here;
* **memory**: every process of the run (by its node name, as bench_cpu names them) is
  sampled from /proc every wall second; its resident memory at the end against its
  resident memory half-way through the run (start-up and the first allocations are
  over by then). Flat: no process grew more than ``RSS_TOL_MB`` in the second half.

Writes bench/results/endurance.json (``endurance_rates_ok``, ``endurance_memory_flat``,
``endurance_rtf`` asked and achieved, per topic the worst minute's rate and the largest
gap, per process the resident memory at a quarter, half and the end) and
endurance.png (rates per minute and resident memory over time).
"""
import json
import os
import subprocess
import sys
import threading
import time
from typing import Dict, List, Tuple

import yaml

from quadrivio_runtime.files import atomic_path

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from bench_cpu import run_processes  # noqa: E402
from common import RESULTS, machine, write_result  # noqa: E402

SIM_S = float(os.environ.get("ENDURANCE_SIM_S", "600"))
RATE_TOL = 0.10  # [1] a minute's rate within 10 % of the configured one
GAP_PERIODS = 5.0  # [1] no gap longer than this many periods
RSS_TOL_MB = 5.0  # [MB] growth of one process over the second half of the run
WINDOW = 60.0  # [s sim] rates per minute


def _yaml(pkg: str, *rel: str) -> dict:
    import rospkg

    with open(os.path.join(rospkg.RosPack().get_path(pkg), *rel)) as fh:
        return yaml.safe_load(fh)


def expected_rates() -> Dict[str, float]:
    """[Hz] of every contract topic with a rate, from the stack's own config files."""
    sim = _yaml("quadrivio_sim", "config", "sim.yaml")
    s = sim["sensors"]
    return {
        "/gps/fix": float(s["gps"]["rate"]),
        "/imu/data": float(s["imu"]["rate"]),
        "/imu/mag": float(s["mag"]["rate"]),
        "/scan/front": float(s["lasers"]["rate"]),
        "/scan/rear": float(s["lasers"]["rate"]),
        "/ground_truth/odom": float(sim["ground_truth_rate"]),
        "/vehicle/state": float(sim["plc"]["state_rate"]),
        "/localization/odom": float(_yaml("quadrivio_localization", "config", "localization.yaml")["rate"]),
        "/localization/predicted": float(_yaml("quadrivio_localization", "config", "predictor.yaml")["rate"]),
        "/vehicle/setpoint/auto": float(_yaml("quadrivio_navigation", "config", "follower.yaml")["rate"]),
    }


def factor() -> float:
    if os.environ.get("ENDURANCE_RTF"):
        return float(os.environ["ENDURANCE_RTF"])
    try:
        with open(os.path.join(RESULTS, "stack.json")) as fh:
            return float(json.load(fh)["stack_rtf"])
    except (OSError, KeyError, ValueError, TypeError):
        return 4.0


def scenario(folder: str) -> str:
    """The figure eight, lap after lap, ending on its duration."""
    from quadrivio.scenario import resolve

    with open(resolve("figure_eight")) as fh:
        data = yaml.safe_load(fh)
    data["name"] = "figure_eight_endurance"
    data["description"] = f"The figure eight driven lap after lap for {SIM_S:g} s (bench_endurance)"
    data["path"] = {"figure_eight": {"laps": int(SIM_S / 50.0) + 2}}  # a lap takes about 54 s at 2 m/s
    data["run"] = dict(data.get("run", {}), max_duration=SIM_S, end="duration")
    os.makedirs(folder, exist_ok=True)
    path = os.path.join(folder, "figure_eight_endurance.yaml")
    with open(path, "w") as fh:
        yaml.safe_dump(data, fh)
    return path


def _rss_mb(pid: str) -> float:
    with open(f"/proc/{pid}/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def sample_memory(stop: threading.Event, running: threading.Event, series: Dict[str, List[Tuple[float, float]]]):
    """``series``: process name -> [(wall s since the run started, resident MB)]."""
    t0 = None
    while not stop.is_set():
        if running.is_set():
            t0 = time.monotonic() if t0 is None else t0
            now = time.monotonic() - t0
            per: Dict[str, float] = {}
            for pid, name in run_processes():
                try:
                    per[name] = per.get(name, 0.0) + _rss_mb(pid)
                except (OSError, IndexError, ValueError):
                    continue  # gone
            for name, mb in per.items():
                series.setdefault(name, []).append((now, mb))
        stop.wait(1.0)


def rates(bag_path: str, expected: Dict[str, float], settle: float = 5.0) -> Dict[str, dict]:
    """Per topic: messages per minute by their header stamps (sim time) from ``settle`` s
    after the first contract message to the last whole minute, and the largest gap.

    Header stamps, not the bag's receipt times: the recorder's clock is its own /clock
    subscription, which at a high factor advances in steps of 0.1-0.2 s behind its
    recording callbacks (a steady 50 Hz stream showed 0.4 s "gaps" in receipt time)."""
    import rosbag

    from quadrivio_sim.ros.converters import header_stamp

    times: Dict[str, List[float]] = {t: [] for t in expected}
    with rosbag.Bag(bag_path) as bag:
        for topic, raw, _t in bag.read_messages(topics=list(expected), raw=True):
            secs, nsecs = header_stamp(raw[1])  # every contract type starts with a Header
            times[topic].append(secs + nsecs * 1e-9)
    stamps = [x for ts in times.values() for x in ts]
    if not stamps:
        raise SystemExit(f"[bench endurance] {bag_path} holds none of the contract topics")
    t0, t1 = min(stamps) + settle, max(stamps)
    window = min(WINDOW, (t1 - t0) / 2.0)  # a short run (ENDURANCE_SIM_S) still gets two windows
    n_win = max(1, int((t1 - t0) // window))
    out = {}
    for topic, hz in expected.items():
        ts = sorted(x for x in times[topic] if t0 <= x < t0 + n_win * window)
        per_min = [0] * n_win
        for x in ts:
            per_min[min(int((x - t0) // window), n_win - 1)] += 1
        per_min = [c / window for c in per_min]
        gaps = [b - a for a, b in zip(ts, ts[1:])]
        gap = max(gaps) if gaps else float("inf")
        # (stamps are whole sim ticks: a gap of exactly GAP_PERIODS periods sums to a hair over it in floats)
        ok = bool(per_min) and all(abs(r - hz) <= RATE_TOL * hz for r in per_min) and gap <= GAP_PERIODS / hz + 1e-6
        out[topic] = {"expected_hz": hz, "per_minute_hz": per_min, "worst_minute_hz": max(per_min, key=lambda r: abs(r - hz)),
                      "max_gap_s": gap, "ok": ok}
    return out


def plot(path: str, topic_rates: Dict[str, dict], memory: Dict[str, List[Tuple[float, float]]], rtf: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(13, 5))
    for topic, r in sorted(topic_rates.items()):
        rel = [x / r["expected_hz"] for x in r["per_minute_hz"]]
        a.plot(range(1, len(rel) + 1), rel, marker="o", label=topic)
    a.axhspan(1 - RATE_TOL, 1 + RATE_TOL, color="0.9", zorder=0)
    a.set_xlabel("minute of simulated time")
    a.set_ylabel("rate / configured rate")
    a.set_title(f"contract topics at factor {rtf:g} (band: ±{RATE_TOL:.0%})")
    a.legend(fontsize=7)
    top = sorted(memory, key=lambda n: -memory[n][-1][1])[:10]
    for name in top:
        s = memory[name]
        b.plot([x for x, _ in s], [y for _, y in s], label=name)
    b.set_xlabel("wall s since the run started")
    b.set_ylabel("resident memory [MB]")
    b.set_title("memory of the run's processes (the 10 largest)")
    b.legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


def main():
    rtf = factor()
    folder = os.path.join(RESULTS, ".endurance")
    scen = scenario(folder)
    out = os.path.join(folder, "run")
    memory: Dict[str, List[Tuple[float, float]]] = {}
    stop, running = threading.Event(), threading.Event()
    th = threading.Thread(target=sample_memory, args=(stop, running, memory), daemon=True)
    th.start()
    print(f"[bench endurance] {SIM_S:g} simulated s of the figure eight at factor {rtf:g} ...", flush=True)
    t_wall = time.monotonic()
    proc = subprocess.Popen(["rosrun", "quadrivio", "experiment", scen, "--rtf", str(rtf), "--out", out,
                             "--wall-timeout", str(int(SIM_S / max(rtf, 0.5) * 3 + 120))],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    tail: List[str] = []
    for line in proc.stdout:
        tail = (tail + [line])[-40:]
        if "] running" in line:
            running.set()
        if "%" in line or "running" in line:
            print("  " + line.rstrip(), flush=True)
    proc.wait()
    stop.set()
    th.join()
    try:
        with open(os.path.join(out, "metrics.json")) as fh:
            m = json.load(fh)
    except OSError:
        print("".join(tail), file=sys.stderr)
        raise SystemExit("[bench endurance] the run wrote no metrics")
    with open(os.path.join(out, "run_info.json")) as fh:
        outcome = json.load(fh)["outcome"]  # "completed": the duration reached, no abort, no node died
    topic_rates = rates(os.path.join(out, "run.bag"), expected_rates())
    grow = {}
    for name, s in memory.items():
        if len(s) < 8:
            continue
        end = s[-1][0]
        at = lambda frac: min(s, key=lambda p: abs(p[0] - frac * end))[1]  # noqa: E731
        grow[name] = {"rss_quarter_mb": at(0.25), "rss_half_mb": at(0.5), "rss_end_mb": s[-1][1],
                      "growth_second_half_mb": s[-1][1] - at(0.5)}
    rates_ok = all(r["ok"] for r in topic_rates.values())
    flat = all(g["growth_second_half_mb"] <= RSS_TOL_MB for g in grow.values())
    result = {"endurance_completed": 1.0 if outcome == "completed" else 0.0, "endurance_outcome": outcome,
              "endurance_rates_ok": 1.0 if rates_ok else 0.0, "endurance_memory_flat": 1.0 if flat else 0.0,
              "endurance_rtf": rtf, "endurance_achieved_rtf": m["rtf"], "endurance_sim_s": m["sim_duration_s"],
              "endurance_wall_s": time.monotonic() - t_wall,
              "endurance_max_growth_mb": max((g["growth_second_half_mb"] for g in grow.values()), default=0.0),
              "xte_rmse_m": m.get("xte_rmse_m"), "xte_max_m": m.get("xte_max_m"), "loc_rmse_m": m.get("loc_rmse_m"),
              "topics": topic_rates, "memory": grow,
              "how": f"scenario figure_eight (seed {m.get('seed')}) lap after lap for {SIM_S:g} s at --rtf {rtf:g}; "
                     f"rates per minute of sim time from the bag within {RATE_TOL:.0%} of the config files', gaps "
                     f"<= {GAP_PERIODS:g} periods; resident memory growth over the second half <= {RSS_TOL_MB:g} MB "
                     "per process",
              "machine": machine()}
    write_result("endurance", result)
    plot(os.path.join(RESULTS, "endurance.png"), topic_rates, memory, rtf)
    for topic, r in sorted(topic_rates.items()):
        print(f"[bench endurance] {topic:26s} {r['expected_hz']:6.1f} Hz: worst minute {r['worst_minute_hz']:7.2f} Hz, "
              f"largest gap {r['max_gap_s']:.3f} s {'ok' if r['ok'] else 'OUT'}", flush=True)
    for name, g in sorted(grow.items(), key=lambda kv: -kv[1]["growth_second_half_mb"])[:6]:
        print(f"[bench endurance] {name:24s} RSS {g['rss_half_mb']:7.1f} -> {g['rss_end_mb']:7.1f} MB "
              f"(+{g['growth_second_half_mb']:.1f})", flush=True)
    print(f"[bench endurance] factor {rtf:g} (achieved {m['rtf']:.2f}): {outcome}, cross-track "
          f"{m.get('xte_rmse_m') or float('nan'):.2f} / {m.get('xte_max_m') or float('nan'):.2f} m, "
          f"rates {'ok' if rates_ok else 'OUT'}, "
          f"memory {'flat' if flat else 'GROWS'}", flush=True)


if __name__ == "__main__":
    main()
