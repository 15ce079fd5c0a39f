"""Benchmark loc_campaign: our smoother and robot_localization side by side on the GNSS
degradation scenarios, the same readings for both, several seeds.

For each scenario of ``SCENARIOS`` and each seed 0 .. N-1 (``LOC_CAMPAIGN_SEEDS``, default
10): one offline run (:mod:`quadrivio.offline`: simulator core, sensor models, our smoother,
the follower on the ground truth so the readings do not depend on the estimator), on a
local Dask cluster; its readings, as delivered to our smoother, are then fed to
robot_localization's EKF and navsat_transform (built from ../shared/peers/ by
tools/build_peers.sh into .peers/) in lockstep sim time (bench/peer_rl.py), with the same
magnetometer calibration ours starts from (the simulated magnetometer's; none in
``uncalibrated``). Both are scored against the ground truth from ``SETTLE`` s on.

The peer's repeatability is measured, not assumed: one run is fed to it ``REPEATS`` times
and the spread of its RMSE is reported (``ekf_repeat_rmse_spread_m``).

Writes bench/results/loc_campaign.json (headline keys at the top level, per scenario the
mean and spread over seeds of ours, the EKF's and the raw GPS's figures, and every run)
and bench/results/loc_campaign.png.
"""
import math
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

from quadrivio_runtime.files import atomic_path

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, HERE)
from common import RESULTS, machine, write_result  # noqa: E402

SCENARIOS = ("rtk", "consumer", "urban_multipath", "long_outage", "gps_latency", "uncalibrated", "dead_wheel")
SETTLE = 20.0  # [s]
REPEATS = 3


def log(text: str) -> None:
    print(f"[loc_campaign {time.strftime('%H:%M:%S')}] {text}", flush=True)


def ours(scenario: str, seed: int, work: str) -> dict:
    """A Dask task: one offline run; saves its inputs and truth for the peer."""
    from quadrivio import offline
    from quadrivio.campaign import flatten
    from quadrivio.scenario import load_scenario

    s = load_scenario(scenario)
    r = offline.run(s, seed)
    fig = flatten(offline.score(r, s, SETTLE))
    cal = offline.localizer_params(s).priors.magnetometer.vectors()[0]
    path = os.path.join(work, f"{s.name}_s{seed}.npz")
    with atomic_path(path) as tmp:
        np.savez_compressed(tmp, state=np.array(r.inputs.state), imu=np.array(r.inputs.imu),
                            mag=np.array(r.inputs.mag), gps=np.array(r.inputs.gps), t_end=r.truth[-1, 0],
                            mag_cal=cal, truth=r.truth, ours=r.estimate[:, :4])
    fig["inputs"] = path
    return fig


def peer(setup: str, inputs: str, out: str) -> np.ndarray:
    r = subprocess.run([sys.executable, os.path.join(HERE, "peer_rl.py"), setup, inputs, out], capture_output=True,
                       text=True, timeout=900)
    if r.returncode != 0:
        raise RuntimeError(f"peer run on {os.path.basename(inputs)} failed: {r.stderr.strip()[-500:]}")
    return np.load(out)["estimate"]


def score_track(est: np.ndarray, truth: np.ndarray, scenario_data: dict) -> dict:
    """RMSE, heading RMSE and outage figures of a track [t, x, y, yaw] against the truth."""
    t = est[:, 0]
    inside = (t >= truth[0, 0]) & (t <= truth[-1, 0])
    e = est[inside]
    x = np.interp(e[:, 0], truth[:, 0], truth[:, 1])
    y = np.interp(e[:, 0], truth[:, 0], truth[:, 2])
    yaw = np.interp(e[:, 0], truth[:, 0], np.unwrap(truth[:, 3]))
    err = np.hypot(e[:, 1] - x, e[:, 2] - y)
    herr = (e[:, 3] - yaw + np.pi) % (2 * np.pi) - np.pi
    late = e[:, 0] >= SETTLE
    out = {"rmse_m": float(np.sqrt(np.mean(err[late] ** 2))),
           "heading_rmse_deg": math.degrees(float(np.sqrt(np.mean(herr[late] ** 2)))),
           "max_error_m": float(err[late].max())}
    sched = (((scenario_data.get("sensors") or {}).get("gps") or {}).get("noise") or {}).get("outages") or {}
    for start, end in sched.get("scheduled", []):
        for key, at in (("outage_end_error_m", end), ("outage_10s_error_m", end + 10.0)):
            i = min(int(np.searchsorted(e[:, 0], at)), len(e) - 1)
            out[key] = float(err[i])
        break
    return out


def mean_sd(values):
    v = np.array([x for x in values if x is not None and math.isfinite(x)], float)
    if not len(v):
        return None, None
    return float(v.mean()), (float(v.std(ddof=1)) if len(v) > 1 else None)


def plot(summary: dict, path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(summary)
    fig, ax = plt.subplots(figsize=(10, 4.5))
    w = 0.2
    for i, (key, figure, label, color) in enumerate((
            ("ours", "rmse_m", "Quadrivio smoother", "tab:blue"),
            ("ekf", "rmse_m", "robot_localization EKF", "tab:orange"),
            ("gps", "oracle_rms_m", "oracle: perfect odometry, true drift model", "0.25"),
            ("gps", "rmse_m", "raw GPS", "0.6"))):
        means = [summary[n][key][figure][0] or 0 for n in names]
        sds = [summary[n][key][figure][1] or 0 for n in names]
        ax.bar(np.arange(len(names)) + (i - 1.5) * w, means, w, yerr=sds, label=label, color=color, capsize=2)
    ax.set_xticks(np.arange(len(names)))
    ax.set_xticklabels(names, rotation=15)
    ax.set_ylabel("position RMSE [m] (mean ± sd over seeds)")
    ax.set_title("Localization on the GNSS degradation scenarios, same readings for both")
    ax.set_yscale("log")
    ax.grid(axis="y", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    from distributed import Client, as_completed

    from quadrivio.campaign import local_cluster
    from quadrivio.scenario import load_scenario

    seeds = list(range(int(os.environ.get("LOC_CAMPAIGN_SEEDS", "10"))))
    build = subprocess.run([os.path.join(ROOT, "tools", "build_peers.sh")], capture_output=True, text=True)
    if build.returncode != 0:
        print(build.stderr, file=sys.stderr)
        log("robot_localization could not be built: see above")
        return 1
    setup = build.stdout.strip().splitlines()[-1]
    work = tempfile.mkdtemp(prefix="loc_campaign_", dir=RESULTS if os.path.isdir(RESULTS) else None)
    data = {n: load_scenario(n).data for n in SCENARIOS}
    jobs = [(n, s) for n in SCENARIOS for s in seeds]
    log(f"{len(SCENARIOS)} scenarios x {len(seeds)} seeds: ours offline on Dask, the peer in lockstep as runs finish")
    runs = []
    wall0 = time.monotonic()
    cluster = local_cluster(os.cpu_count() or 1)  # one BLAS thread each, no Dask profiler
    client = Client(cluster)
    try:
        futures = {client.submit(ours, n, s, work, pure=False): (n, s) for n, s in jobs}
        for fut in as_completed(futures):
            n, s = futures[fut]
            fig = fut.result()
            d = np.load(fig["inputs"])
            est = peer(setup, fig["inputs"], os.path.join(work, f"{n}_s{s}_ekf.npz"))
            ekf = score_track(est, d["truth"], data[n])
            run = {"scenario": n, "seed": s, "ours": {k: v for k, v in fig.items() if k not in ("inputs",)},
                   "ekf": ekf}
            runs.append(run)
            log(f"{len(runs)}/{len(jobs)} {n} seed {s}: ours {fig['rmse_m']:.3f} m, EKF {ekf['rmse_m']:.3f} m, "
                f"raw GPS {fig['gps_rmse_m']:.3f} m ({time.monotonic() - wall0:.0f} s)")
    finally:
        client.close()
        cluster.close()
    # the peer's repeatability on one input set
    first = os.path.join(work, f"consumer_s{seeds[0]}.npz")
    d = np.load(first)
    repeat = [score_track(peer(setup, first, os.path.join(work, f"repeat{i}.npz")), d["truth"],
                          data["consumer"])["rmse_m"] for i in range(REPEATS)]
    log(f"peer repeatability, consumer seed {seeds[0]} x{REPEATS}: RMSE {', '.join(f'{r:.4f}' for r in repeat)} m")

    summary = {}
    for n in SCENARIOS:
        rs = [r for r in runs if r["scenario"] == n]
        entry = {"ours": {}, "ekf": {}, "gps": {}}
        for key in ("rmse_m", "heading_rmse_deg", "max_error_m", "outage_end_error_m", "outage_10s_error_m"):
            entry["ours"][key] = mean_sd([r["ours"].get(key) for r in rs])
            entry["ekf"][key] = mean_sd([r["ekf"].get(key) for r in rs])
        entry["gps"]["rmse_m"] = mean_sd([r["ours"]["gps_rmse_m"] for r in rs])
        entry["gps"]["drift_rms_m"] = mean_sd([r["ours"].get("gps_drift_rms_m") for r in rs])
        entry["gps"]["oracle_rms_m"] = mean_sd([r["ours"].get("gps_oracle_rms_m") for r in rs])
        entry["oracle_vs_ekf"] = mean_sd([r["ours"]["gps_oracle_rms_m"] / r["ekf"]["rmse_m"] for r in rs])
        for key in ("steer_offset_error_deg", "wheel_scale_error_pct", "dead_wheel_named_after_s", "update_p99_ms",
                    "update_cpu_p99_ms", "cpu_frac"):
            entry["ours"][key] = mean_sd([r["ours"].get(key) for r in rs])
        entry["ours_vs_gps"] = mean_sd([r["ours"]["rmse_m"] / r["ours"]["gps_rmse_m"] for r in rs])
        entry["ours_vs_ekf"] = mean_sd([r["ours"]["rmse_m"] / r["ekf"]["rmse_m"] for r in rs])
        summary[n] = entry
    by = {(r["scenario"], r["seed"]): r for r in runs}
    multipath_ratio = mean_sd([by[("urban_multipath", s)]["ours"]["rmse_m"] / by[("consumer", s)]["ours"]["rmse_m"]
                               for s in seeds])
    recovery = mean_sd([by[("long_outage", s)]["ours"]["outage_10s_error_m"] - by[("rtk", s)]["ours"]["rmse_m"]
                        for s in seeds])
    result = {
        "loc_consumer_vs_gps_ratio": summary["consumer"]["ours_vs_gps"][0],
        "loc_consumer_vs_ekf_ratio": summary["consumer"]["ours_vs_ekf"][0],
        # the receiver's drift alone (the simulator's state, which no GNSS-only estimate sees):
        # both estimators' floor, so what a ratio to the EKF can reach
        "loc_consumer_vs_drift_ratio": mean_sd([by[("consumer", s)]["ours"]["rmse_m"]
                                                / by[("consumer", s)]["ours"]["gps_drift_rms_m"] for s in seeds])[0],
        "ekf_consumer_vs_drift_ratio": mean_sd([by[("consumer", s)]["ekf"]["rmse_m"]
                                                / by[("consumer", s)]["ours"]["gps_drift_rms_m"] for s in seeds])[0],
        # the GNSS oracle (quadrivio.gnss_bound: perfect odometry and the receiver's true drift
        # model) on the same fixes: the lowest ratio to the EKF any estimator reaches in expectation
        "oracle_consumer_vs_ekf_ratio": summary["consumer"]["oracle_vs_ekf"][0],
        "loc_consumer_vs_oracle_ratio": mean_sd([by[("consumer", s)]["ours"]["rmse_m"]
                                                 / by[("consumer", s)]["ours"]["gps_oracle_rms_m"] for s in seeds])[0],
        "loc_multipath_vs_consumer_ratio": multipath_ratio[0],
        "loc_outage_end_error_m": summary["long_outage"]["ours"]["outage_end_error_m"][0],
        "loc_outage_recovery_10s_minus_rtk_rmse_m": recovery[0],
        "loc_steer_offset_error_deg": mean_sd([abs(by[("uncalibrated", s)]["ours"]["steer_offset_error_deg"])
                                               for s in seeds])[0],
        "loc_wheel_scale_error_pct": mean_sd([abs(by[("uncalibrated", s)]["ours"]["wheel_scale_error_pct"])
                                              for s in seeds])[0],
        "loc_uncalibrated_heading_rmse_deg": summary["uncalibrated"]["ours"]["heading_rmse_deg"][0],
        "loc_dead_wheel_vs_gps_ratio": summary["dead_wheel"]["ours_vs_gps"][0],
        "loc_dead_wheel_named_after_s": summary["dead_wheel"]["ours"]["dead_wheel_named_after_s"][0],
        "smoother_update_p99_ms_max": max(r["ours"]["update_p99_ms"] for r in runs),
        # the same updates' CPU time: the wall time above includes waiting for a core, with
        # two runs and the peer sharing this machine's two
        "smoother_update_cpu_p99_ms_max": max(r["ours"].get("update_cpu_p99_ms", math.nan) for r in runs),
        "smoother_cpu_frac_max": max(r["ours"]["cpu_frac"] for r in runs),
        "ekf_repeat_rmse_spread_m": float(np.ptp(repeat)),
        "seeds": seeds, "settle_s": SETTLE, "scenarios": summary, "runs": runs,
        "peer": "robot_localization 2.7.5 (../shared/peers, commit 7bebbed) ekf_localization_node two_d_mode + "
                "navsat_transform_node, lockstep sim time (bench/peer_rl.py)",
        "machine": machine(), "wall_s": time.monotonic() - wall0,
    }
    write_result("loc_campaign", result)
    plot(summary, os.path.join(RESULTS, "loc_campaign.png"))
    for n in SCENARIOS:
        e = summary[n]
        log(f"{n:16s} ours {e['ours']['rmse_m'][0]:.3f} m  EKF {e['ekf']['rmse_m'][0]:.3f} m  "
            f"GPS {e['gps']['rmse_m'][0]:.3f} m  oracle {e['gps']['oracle_rms_m'][0] or math.nan:.3f} m  ours/GPS {e['ours_vs_gps'][0]:.2f}  ours/EKF {e['ours_vs_ekf'][0]:.2f}")
    import shutil
    shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
