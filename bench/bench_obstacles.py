"""The obstacle guard, the local obstacle layer and replanning, over scenarios x seeds x speeds
(issue: see and stop). Writes bench/results/obstacles.json and obstacles.md (the table).

Every run goes through ``rosrun quadrivio experiment`` (the whole stack, free-running at
``--rtf``), on a copy of each scenario with the follower's speed set (2 and 3 m/s by
default) and the seed given:

* with obstacles: person_on_path (a person stands on the figure eight, then walks away),
  orchard_crossing (a person crosses the lane 8 m ahead), orchard_blocked (a vehicle parked
  in the lane: stop, replan, park), laser_dropout (the front laser falls silent), zone_edge
  (the operating zone's edge across the eight);
* without: figure_eight, orchard, rough_terrain (false stops must be 0).

Keys: ``obstacle_collisions`` (contacts over every run), ``obstacle_min_clearance_m`` (the
smallest true clearance of the runs with actors), ``obstacle_false_stops`` (protective
stops with nothing in the field, in the runs without obstacles; ``obstacle_false_stops_all``
over every run), ``obstacle_stop_latency_p99_ms`` (scan stamp to the guarded stop
setpoint, every protective stop), ``obstacle_replan_completed`` (orchard_blocked runs that
parked at the goal), ``laser_dropout_stop_s_max`` (the silent laser's last scan to the
vehicle's standstill), ``zone_exits`` (runs whose true footprint left the zone);
``guard_cpu_frac`` (the guard's CPU seconds per simulated second in a factor-1 run of
person_on_path; ``guard_cpu_frac_python``: the Python reference guard's in the same run again) and ``local_layer_update_p99_ms`` (its scans replayed into the layer
in this process, one update per scan).

``--seeds N`` (default 10), ``--speeds 2,3``, ``--rtf`` (default 2), ``--only a,b``, ``--guard
guard`` (the Python reference guard in the scenario runs; default guard_cpp).
"""
import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import yaml

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, machine, write_result  # noqa: E402

WITH = ("person_on_path", "orchard_crossing", "dog_runs_out", "orchard_blocked", "laser_dropout", "zone_edge")
WITHOUT = ("figure_eight", "orchard", "rough_terrain")


def variant(name: str, speed: float, folder: str) -> str:
    """A copy of scenario ``name`` with the follower's speed set (paths made absolute)."""
    from quadrivio.scenario import resolve

    src = resolve(name)
    with open(src) as fh:
        data = yaml.safe_load(fh)
    data.setdefault("follower", {}).setdefault("profile", {})["speed"] = speed
    if "map" in data and "file" in data["map"] and not os.path.isabs(data["map"]["file"]):
        data["map"]["file"] = os.path.normpath(os.path.join(os.path.dirname(src), data["map"]["file"]))
    if "map" in data:  # the lattice's first solution needs over 2 s beside a stack at factor 2
        data.setdefault("planner", {}).setdefault("budget", 5.0)
    data["name"] = f"{name}_{speed:g}mps"
    path = os.path.join(folder, f"{data['name']}.yaml")
    with open(path, "w") as fh:
        yaml.safe_dump(data, fh)
    return path


def run(path: str, seed: int, out: str, rtf: float, cpu_node: str = "", extra=()) -> dict:
    if os.path.isdir(out):
        shutil.rmtree(out)
    cmd = ["rosrun", "quadrivio", "experiment", path, "--seed", str(seed), "--rtf", str(rtf), "--out", out,
           "--wall-timeout", "900"] + list(extra)
    cpu = {}
    stop = threading.Event()
    if cpu_node:
        th = threading.Thread(target=_watch_cpu, args=(cpu_node, stop, cpu), daemon=True)
        th.start()
    t0 = time.monotonic()
    p = subprocess.run(cmd, capture_output=True, text=True)
    stop.set()
    metrics = os.path.join(out, "metrics.json")
    if not os.path.isfile(metrics):
        print(p.stdout[-1500:], p.stderr[-1500:], file=sys.stderr)
        return {"failed": True, "exit": p.returncode, "out": out}
    with open(metrics) as fh:
        m = json.load(fh)
    m.update(out=out, wall_s=time.monotonic() - t0, exit=p.returncode, cpu=cpu)
    return m


def _watch_cpu(node: str, stop: threading.Event, out: dict) -> None:
    """The node's CPU seconds (user + system) from its first sample to its last."""
    tick = os.sysconf("SC_CLK_TCK")
    first = last = None
    while not stop.wait(0.5):
        for pid in os.listdir("/proc"):
            if not pid.isdigit():
                continue
            try:
                with open(f"/proc/{pid}/cmdline", "rb") as fh:
                    if f"__name:={node}".encode() not in fh.read():
                        continue
                with open(f"/proc/{pid}/stat") as fh:
                    f = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            c = (int(f[11]) + int(f[12])) / tick
            first = c if first is None else first
            last = c
            out["cpu_s"] = last - first


def layer_update_ms(bag_path: str):
    """Each scan of a run's bag replayed into a LocalLayer at the predicted pose: update times [ms]."""
    import rosbag

    from quadrivio_description.frames import yaw_from_quaternion
    from quadrivio_navigation.local_layer import LocalLayer, LocalLayerParams

    layer = LocalLayer(LocalLayerParams())
    mounts = {"laser_front": (1.60, 0.0, 0.0), "laser_rear": (-0.38, 0.0, math.pi)}
    pose, times = None, []
    with rosbag.Bag(bag_path) as bag:
        for topic, m, _ in bag.read_messages(topics=["/scan/front", "/scan/rear", "/localization/predicted"]):
            if topic == "/localization/predicted":
                q = m.pose.pose.orientation
                pose = (m.pose.pose.position.x, m.pose.pose.position.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
                continue
            if pose is None:
                continue
            mx, my, myaw = mounts[m.header.frame_id]
            c, s = math.cos(pose[2]), math.sin(pose[2])
            sensor = (pose[0] + c * mx - s * my, pose[1] + s * mx + c * my, pose[2] + myaw)
            bearings = m.angle_min + m.angle_increment * np.arange(len(m.ranges))
            t0 = time.perf_counter()
            layer.add_scan(m.header.stamp.to_sec(), sensor, bearings, np.asarray(m.ranges, dtype=float))
            times.append(1e3 * (time.perf_counter() - t0))
    return times


def zone_exit(out: str, zone) -> bool:
    """Whether the true (unpadded) footprint left the zone at any ground-truth sample."""
    import rosbag

    from quadrivio_description.frames import yaw_from_quaternion
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.guard import points_in_polygon

    fp = Footprint.from_vehicle(load_vehicle())
    poly = np.asarray(zone, dtype=float)
    with rosbag.Bag(os.path.join(out, "run.bag")) as bag:
        for _, m, _ in bag.read_messages(topics=["/ground_truth/odom"]):
            p, q = m.pose.pose.position, m.pose.pose.orientation
            c = fp.corners(p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w))
            if not points_in_polygon(c, poly).all():
                return True
    return False


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--speeds", default="2,3")
    ap.add_argument("--rtf", type=float, default=2.0)
    ap.add_argument("--only", default="", help="comma-separated scenario names")
    ap.add_argument("--guard", choices=("guard_cpp", "guard"), default="guard_cpp",
                    help="the guard of the scenario runs (the CPU runs measure both)")
    ap.add_argument("--out", default=os.path.join(tempfile.gettempdir(), "quadrivio_bench_obstacles"))
    args = ap.parse_args()
    speeds = [float(s) for s in args.speeds.split(",")]
    names = [n for n in WITH + WITHOUT if not args.only or n in args.only.split(",")]
    os.makedirs(args.out, exist_ok=True)
    runs = []
    t_start = time.monotonic()
    total = len(names) * len(speeds) * args.seeds
    k = 0
    for name in names:
        for speed in speeds:
            path = variant(name, speed, args.out)
            for seed in range(args.seeds):
                k += 1
                out = os.path.join(args.out, f"{name}_{speed:g}_s{seed}")
                m = run(path, seed, out, args.rtf, extra=["--guard", args.guard])
                m.update(scenario=name, speed=speed, seed=seed)
                runs.append(m)
                print(f"[bench obstacles] {k}/{total} {name} {speed:g} m/s seed {seed}: "
                      f"{'FAILED' if m.get('failed') else 'completed' if m.get('completed') else 'not completed'}, "
                      f"collisions {m.get('collisions')}, clearance {m.get('min_clearance_m')}, "
                      f"stops {m.get('protective_stops')} (false {m.get('false_stops')}), "
                      f"{time.monotonic() - t_start:.0f} s", flush=True)
    ok = [r for r in runs if not r.get("failed")]
    result = {"machine": machine(), "seeds": args.seeds, "speeds": speeds, "rtf": args.rtf, "guard": args.guard,
              "runs": len(runs),
              "runs_failed": len(runs) - len(ok)}
    result["obstacle_collisions"] = int(sum(r.get("collisions") or 0 for r in ok))
    clear = [r["min_clearance_m"] for r in ok if r["scenario"] in WITH and r.get("min_clearance_m") is not None]
    result["obstacle_min_clearance_m"] = float(min(clear)) if clear else None
    result["obstacle_false_stops"] = int(sum(r.get("false_stops") or 0 for r in ok if r["scenario"] in WITHOUT))
    result["obstacle_false_stops_all"] = int(sum(r.get("false_stops") or 0 for r in ok))
    lat = [x for r in ok for x in (r.get("stop_latencies_ms") or [])]
    result["obstacle_stop_latency_p99_ms"] = float(np.percentile(lat, 99)) if lat else None
    result["obstacle_stop_latency_max_ms"] = float(max(lat)) if lat else None
    result["obstacle_protective_stops"] = len(lat)
    blocked = [r for r in runs if r["scenario"] == "orchard_blocked"]
    if blocked:
        result["obstacle_replan_completed"] = float(np.mean([bool(r.get("completed")) for r in blocked]))
    zoned = [r for r in ok if r["scenario"] == "zone_edge"]
    if zoned:
        from quadrivio.scenario import load_scenario

        zone = load_scenario("zone_edge").data["guard"]["zone"]
        result["zone_exits"] = int(sum(zone_exit(r["out"], zone) for r in zoned))
        result["zone_stops"] = int(sum(r.get("zone_stops") or 0 for r in zoned))
    dropout = [r for r in ok if r["scenario"] == "laser_dropout"]
    if dropout:
        result["laser_dropout_fault_stops"] = int(sum(r.get("fault_stops") or 0 for r in dropout))
    per = {}
    for r in ok:
        key = f"{r['scenario']} {r['speed']:g} m/s"
        per.setdefault(key, []).append(r)
    result["per_scenario"] = {
        key: {"runs": len(rs), "completed": float(np.mean([bool(r.get("completed")) for r in rs])),
              "collisions": int(sum(r.get("collisions") or 0 for r in rs)),
              "min_clearance_m": min((r["min_clearance_m"] for r in rs if r.get("min_clearance_m") is not None),
                                     default=None),
              "protective_stops": int(sum(r.get("protective_stops") or 0 for r in rs)),
              "false_stops": int(sum(r.get("false_stops") or 0 for r in rs)),
              "fault_stops": int(sum(r.get("fault_stops") or 0 for r in rs)),
              "time_blocked_s_mean": float(np.mean([r.get("time_blocked_s") or 0.0 for r in rs])),
              "xte_max_m": max((r["xte_max_m"] for r in rs if r.get("xte_max_m") is not None), default=None)}
        for key, rs in per.items()}
    # the guard's CPU and the layer's update time, from a factor-1 run
    if "person_on_path" in names:
        out = os.path.join(args.out, "cpu_person_on_path")
        m = run(variant("person_on_path", 2.0, args.out), 1, out, 1.0, cpu_node="guard")
        if not m.get("failed") and m.get("cpu", {}).get("cpu_s") is not None:
            result["guard_cpu_frac"] = m["cpu"]["cpu_s"] / m["sim_duration_s"]
        # the Python reference guard, the same run right after (the same decisions: test_guard_native.py)
        ref = run(variant("person_on_path", 2.0, args.out), 1, out + "_python_guard", 1.0, cpu_node="guard",
                  extra=["--guard", "guard"])
        if not ref.get("failed") and ref.get("cpu", {}).get("cpu_s") is not None:
            result["guard_cpu_frac_python"] = ref["cpu"]["cpu_s"] / ref["sim_duration_s"]
            print(f"[bench obstacles] guard CPU per simulated s: roscpp {result.get('guard_cpu_frac')}, "
                  f"Python {result['guard_cpu_frac_python']}", flush=True)
        times = layer_update_ms(os.path.join(out, "run.bag")) if not m.get("failed") else []
        if times:
            result["local_layer_update_p99_ms"] = float(np.percentile(times, 99))
            result["local_layer_update_p50_ms"] = float(np.percentile(times, 50))
            result["local_layer_updates"] = len(times)
    write_result("obstacles", result)
    with open(os.path.join(RESULTS, "obstacles.md"), "w") as fh:
        fh.write("| scenario | runs | completed | collisions | min clearance [m] | protective stops | false | "
                 "fail-safe | blocked mean [s] |\n|---|---|---|---|---|---|---|---|---|\n")
        for key, row in result["per_scenario"].items():
            mc = row["min_clearance_m"]
            fh.write(f"| {key} | {row['runs']} | {row['completed']:.2f} | {row['collisions']} | "
                     f"{'' if mc is None else f'{mc:.2f}'} | {row['protective_stops']} | {row['false_stops']} | "
                     f"{row['fault_stops']} | {row['time_blocked_s_mean']:.1f} |\n")


if __name__ == "__main__":
    main()
