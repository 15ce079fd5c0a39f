"""Benchmark smoother_hour: the smoother's update time, CPU share and memory over one
simulated hour at 20 Hz, in blocks of ten minutes: flat, or not.

The ``consumer`` scenario (metre-level fixes, the costliest GNSS handling: look-ahead
groups, fixes decided a second late) with its figure eight repeated for an hour, run
offline (:mod:`quadrivio.offline`: simulator core, sensor models, our smoother, the
follower on the ground truth) in this process alone. Per block: update p50/p99/max, the
smoother's wall time over simulated time (``cpu_frac``), the process's resident memory at
the block's end (it includes the run's own recording of truth and estimate, a few MB an
hour), the smoother's state (iSAM2's factor slots, the window's keys), and the position
RMSE.

Headline keys: ``smoother_hour_update_p99_ms`` (worst block), ``smoother_hour_cpu_frac``
(worst block), ``smoother_hour_p99_last_over_first`` and ``smoother_hour_rss_growth_mb``
(last block's end against the first's), ``smoother_hour_factor_slots_growth``, and
``smoother_update_p99_ms`` / ``smoother_cpu_frac`` over the whole hour; ``pace_ms_before`` /
``_after``, the machine's pace around the run (bench/common.py). Writes bench/results/smoother_hour.json and
smoother_hour.png. ``SMOOTHER_HOUR_S`` shortens the run (for a quick look).
"""
import math
import os
import sys
import tempfile
import time

import numpy as np
import yaml

from quadrivio_runtime.files import atomic_path

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, machine, pace_ms, write_result  # noqa: E402

DURATION = float(os.environ.get("SMOOTHER_HOUR_S", "3600"))
BLOCK = 600.0  # [s]
LAP_S = 52.0  # [s] one lap of the figure eight at 2 m/s, about
RATE = 20.0  # [Hz] the smoother's update rate (LocalizerParams.rate)


def rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 1e6


def main() -> None:
    from quadrivio import offline
    from quadrivio.scenario import load_scenario, resolve

    pace_before = pace_ms()  # the machine's speed swings 2.4 times within a day: say how fast it was
    with open(resolve("consumer")) as fh:
        data = yaml.safe_load(fh)
    data["name"] = "consumer_hour"
    data["path"] = {"figure_eight": {"laps": int(math.ceil(DURATION / LAP_S)) + 1}}
    data["run"] = {"rtf": 1.0, "max_duration": DURATION, "end": "duration"}
    with tempfile.TemporaryDirectory() as tmp:
        path = os.path.join(tmp, "consumer_hour.yaml")
        with open(path, "w") as fh:
            yaml.safe_dump(data, fh)
        s = load_scenario(path)
        memory = []  # (sim t, rss MB, factor slots in iSAM2, keys in the window)
        made = []

        def factory(*args):
            from quadrivio_localization.smoother import Localizer
            made.append(Localizer(*args))
            return made[-1]

        def state() -> tuple:
            w = made[-1].smoother if made else None
            if w is None:
                return 0, 0
            return int(w.isam.getFactorsUnsafe().size()), len(w.stamps)
        wall0 = time.time()
        last = [-BLOCK]

        def progress(t: float, t_end: float) -> None:
            if t - last[0] >= 60.0 - 1e-6:
                last[0] = t
                memory.append((t, rss_mb()) + state())
                print(f"[smoother_hour] {t:6.0f} / {t_end:.0f} s simulated, {time.time() - wall0:5.0f} s wall, "
                      f"RSS {memory[-1][1]:.0f} MB, iSAM2 factor slots {memory[-1][2]}, window keys "
                      f"{memory[-1][3]}", flush=True)

        r = offline.run(s, seed=0, localizer_factory=factory, progress=progress, record_inputs=False)
    after = rss_mb()  # the run's recording lists freed (its arrays kept)
    ms = np.asarray(r.update_ms)
    cpu_ms = np.asarray(r.update_cpu_ms)
    t_upd = np.arange(len(ms)) / RATE
    err = offline.errors(r)
    blocks = []
    for b0 in np.arange(0.0, DURATION - 1e-6, BLOCK):
        b1 = min(b0 + BLOCK, DURATION)  # a run shorter than a block (SMOOTHER_HOUR_S) is one short block
        in_block = (t_upd >= b0) & (t_upd < b1)
        sel, sel_cpu = ms[in_block], cpu_ms[in_block]
        e = err[(err[:, 0] >= max(b0, 20.0)) & (err[:, 0] < b1)]
        mem = [m for m in memory if m[0] <= b1 + 1e-6]
        if len(sel) == 0:
            continue
        blocks.append({"t0_s": float(b0), "t1_s": float(b1), "updates": int(len(sel)),
                       "update_p50_ms": float(np.percentile(sel, 50)), "update_p99_ms": float(np.percentile(sel, 99)),
                       "update_max_ms": float(sel.max()), "cpu_frac": float(sel.sum() / 1e3 / (b1 - b0)),
                       "update_cpu_p99_ms": float(np.percentile(sel_cpu, 99)),
                       "rss_mb": float(mem[-1][1]) if mem else math.nan,
                       "isam2_factor_slots": int(mem[-1][2]) if mem else 0, "window_keys": int(mem[-1][3]) if mem else 0,
                       "rmse_m": float(np.sqrt(np.mean(e[:, 1] ** 2))) if len(e) else math.nan})
    first, final = blocks[0], blocks[-1]
    result = {
        "machine": machine(), "pace_ms_before": pace_before, "pace_ms_after": pace_ms(),
        "scenario": "consumer, figure eight repeated, offline", "seed": 0,
        "simulated_s": float(r.truth[-1, 0]), "wall_s": float(r.wall), "blocks": blocks,
        "smoother_update_p99_ms": float(np.percentile(ms, 99)), "smoother_cpu_frac": float(r.cpu_frac),
        "smoother_hour_update_p99_ms": max(b["update_p99_ms"] for b in blocks),
        "smoother_hour_cpu_frac": max(b["cpu_frac"] for b in blocks),
        "smoother_hour_p99_last_over_first": final["update_p99_ms"] / first["update_p99_ms"],
        # During the run the process also holds its recording of truth and estimates (about
        # 1 MB a simulated minute, as Python lists): the growth is read after the run, when
        # those lists are gone, against the first block's end.
        "rss_after_run_mb": after,
        "smoother_hour_rss_growth_mb": after - first["rss_mb"],
        "smoother_hour_factor_slots_growth": final["isam2_factor_slots"] - first["isam2_factor_slots"],
        "restarts": int(r.counters.get("restarts", 0)),
    }
    write_result("smoother_hour", result)
    plot(t_upd, ms, blocks, os.path.join(RESULTS, "smoother_hour.png"))
    for b in blocks:
        print(f"[smoother_hour] {b['t0_s']:5.0f}-{b['t1_s']:5.0f} s: p50 {b['update_p50_ms']:.2f} ms, p99 "
              f"{b['update_p99_ms']:.2f} ms, max {b['update_max_ms']:.1f} ms, CPU {b['cpu_frac']:.3f}, "
              f"RSS {b['rss_mb']:.0f} MB, RMSE {b['rmse_m']:.2f} m", flush=True)


def plot(t, ms, blocks, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 6), sharex=True)
    a.plot(t / 60.0, ms, ",", alpha=0.4, label="each update")
    mid = [(x["t0_s"] + x["t1_s"]) / 120.0 for x in blocks]
    a.plot(mid, [x["update_p99_ms"] for x in blocks], "o-", label="p99 per 10 min")
    a.plot(mid, [x["update_p50_ms"] for x in blocks], "s-", label="p50 per 10 min")
    a.set_ylabel("update [ms]")
    a.set_ylim(0, max(10.0, 1.5 * max(x["update_p99_ms"] for x in blocks)))
    a.legend(loc="upper right")
    a.set_title("smoother on one simulated hour (consumer GNSS, 20 Hz)")
    b.plot(mid, [x["rss_mb"] for x in blocks], "o-")
    b.set_ylabel("process RSS [MB]")
    b.set_xlabel("simulated time [min]")
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)


if __name__ == "__main__":
    main()
