"""The obstacle guard, the local obstacle layer and replanning, over scenarios x seeds x speeds
(issue: see and stop). Writes bench/results/obstacles.json and obstacles.md (the table).

Every scenario runs on a copy with the follower's speed set (2 and 3 m/s by default) and the
seed given. The outcomes (collisions, clearance, stops, completion) come from the closed loop
in one process (``quadrivio.closed_loop``, deterministic, 2 local workers: 10 seeds of every
scenario in minutes; ``--runner ros`` runs them through ``rosrun quadrivio experiment``
instead, free-running at ``--rtf``); what only the ROS stack shows (the stop latency through
the topics, the guard's CPU) comes from ROS runs at factor 1 (``--latency-seeds``):

* with obstacles: person_on_path (a person stands on the figure eight, then walks away),
  orchard_crossing (a person crosses the lane 8 m ahead), orchard_blocked (a vehicle parked
  in the lane: stop, replan, park), laser_dropout (the front laser falls silent), zone_edge
  (the operating zone's edge across the eight);
* without: figure_eight, orchard, rough_terrain (false stops must be 0).

Keys: ``obstacle_collisions`` (contacts over every run), ``obstacle_min_clearance_m`` (the
smallest true clearance of the runs with actors), ``obstacle_false_stops`` (protective
stops with nothing in the field, in the runs without obstacles; ``obstacle_false_stops_all``
over every run), ``obstacle_stop_latency_p99_ms`` (scan stamp to the guarded stop
setpoint, every protective stop of the ROS runs at factor 1), ``obstacle_replan_completed`` (orchard_blocked runs that
parked at the goal), ``laser_dropout_stop_s_max`` (the silent laser's last scan to the
vehicle's standstill), ``zone_exits`` (runs whose true footprint left the zone);
``guard_cpu_frac`` (the guard's CPU seconds per simulated second in a factor-1 run of
person_on_path; ``guard_cpu_floor_frac``: in that run, beside it, guard_inputs_sink's, a roscpp
node with the guard's subscriptions that does nothing with them: the floor of delivering the
guard's inputs, as a ratio to the guard's CPU over the same seconds; ``guard_cpu_frac_python``:
the Python reference guard's in the same run again) and ``local_layer_update_p99_ms`` (its scans replayed into the layer
in this process, one update per scan).

``--seeds N`` (default 10), ``--speeds 2,3``, ``--only a,b``, ``--runner in_process|ros``,
``--workers`` (in process, default 2), ``--rtf`` (``--runner ros``, default 2), ``--guard
guard`` (ROS runs: the Python reference guard; default guard_cpp), ``--latency-seeds N``
(ROS runs at factor 1 of dog_runs_out and orchard_crossing at each speed, default 2). A run
with fewer (``--only``, ``--seeds`` under 10, other speeds, ``--latency-seeds`` under 2)
writes bench/results/obstacles_partial.json and .md: the full run's figures stay.
"""
import argparse
import json
import math
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np
import yaml

from quadrivio_runtime.files import atomic_write

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, machine, write_result  # noqa: E402

WITH = ("person_on_path", "orchard_crossing", "dog_runs_out", "orchard_blocked", "laser_dropout", "zone_edge")
WITHOUT = ("figure_eight", "orchard", "rough_terrain")
LATENCY = ("dog_runs_out", "orchard_crossing")  # ROS runs at factor 1 for the stop latency


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


def _node_pids(node: str):
    """The processes started as ROS node ``node`` (``__name:=node`` among their arguments)."""
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                if f"__name:={node}".encode() in fh.read().split(b"\0"):
                    yield pid
        except OSError:
            continue


def _sink_beside(node: str, stop: threading.Event, out: dict) -> None:
    """Once ``node`` runs, start guard_inputs_sink (the guard's subscriptions and nothing else)
    on its master as ``guard_floor``, and its CPU seconds into ``out`` as _watch_cpu does:
    the floor under the guard's CPU, in the same run."""
    env = None
    while env is None and not stop.wait(0.5):
        for pid in _node_pids(node):
            try:
                with open(f"/proc/{pid}/environ", "rb") as fh:
                    env = dict(kv.split(b"=", 1) for kv in fh.read().split(b"\0") if b"=" in kv)
                break
            except OSError:
                continue
    if env is None:
        return
    uri = env.get(b"ROS_MASTER_URI", b"").decode()
    sink = subprocess.Popen(["rosrun", "quadrivio_navigation", "guard_inputs_sink", "__name:=guard_floor"],
                            env=dict(os.environ, ROS_MASTER_URI=uri), stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    try:
        _watch_cpu("guard_floor", stop, out)
    finally:
        sink.send_signal(signal.SIGINT)  # roscpp's shutdown: it prints its counts
        try:
            text = sink.communicate(timeout=10)[0]
        except subprocess.TimeoutExpired:
            sink.kill()
            text = sink.communicate()[0]
        out["received"] = " ".join(line for line in text.splitlines() if "received" in line)


def run(path: str, seed: int, out: str, rtf: float, cpu_node: str = "", extra=(), floor: dict = None) -> dict:
    if os.path.isdir(out):
        shutil.rmtree(out)
    cmd = ["rosrun", "quadrivio", "experiment", path, "--seed", str(seed), "--rtf", str(rtf), "--out", out,
           "--wall-timeout", "900"] + list(extra)
    cpu = {}
    stop = threading.Event()
    if cpu_node:
        th = threading.Thread(target=_watch_cpu, args=(cpu_node, stop, cpu), daemon=True)
        th.start()
    if floor is not None:
        fl = threading.Thread(target=_sink_beside, args=(cpu_node, stop, floor), daemon=True)
        fl.start()
    t0 = time.monotonic()
    p = subprocess.run(cmd, capture_output=True, text=True)
    stop.set()
    if floor is not None:
        fl.join(timeout=30)
    metrics = os.path.join(out, "metrics.json")
    if not os.path.isfile(metrics):
        print(p.stdout[-1500:], p.stderr[-1500:], file=sys.stderr)
        return {"failed": True, "exit": p.returncode, "out": out}
    with open(metrics) as fh:
        m = json.load(fh)
    m.update(out=out, wall_s=time.monotonic() - t0, exit=p.returncode, cpu=cpu)
    return m


def run_in_process(job) -> dict:
    """One run in one process (a pool worker): the metrics, and with a zone whether the true
    footprint left it."""
    path, seed, out, zone = job
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    from quadrivio import closed_loop
    from quadrivio.scenario import load_scenario

    t0 = time.monotonic()
    try:
        s = load_scenario(path)
        r = closed_loop.run(s, seed)
        m = dict(closed_loop.write_run(r, s, seed, out))
    except Exception as exc:  # one bad run is reported, the others go on
        return {"failed": True, "error": f"{type(exc).__name__}: {exc}", "out": out}
    if zone:
        gt = r.run.ground_truth
        m["zone_exit"] = footprint_left(zone, zip(gt["x"], gt["y"], gt["yaw"]))
    m.update(out=out, wall_s=time.monotonic() - t0)
    return m


def footprint_left(zone, poses) -> bool:
    """Whether the true (unpadded) footprint left the zone at any of ``poses`` (x, y, yaw)."""
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.guard import points_in_polygon

    fp = Footprint.from_vehicle(load_vehicle())
    poly = np.asarray(zone, dtype=float)
    return any(not points_in_polygon(fp.corners(x, y, yaw), poly).all() for x, y, yaw in poses)


def _watch_cpu(node: str, stop: threading.Event, out: dict) -> None:
    """The node's CPU seconds (user + system) from its first sample to its last."""
    tick = os.sysconf("SC_CLK_TCK")
    first = last = None
    while not stop.wait(0.5):
        for pid in _node_pids(node):
            try:
                with open(f"/proc/{pid}/stat") as fh:
                    f = fh.read().rsplit(")", 1)[1].split()
            except OSError:
                continue
            c = (int(f[11]) + int(f[12])) / tick
            first = c if first is None else first
            last = c
            out["cpu_s"] = last - first
            out.setdefault("samples", []).append((time.monotonic(), c))


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
    """Whether the true footprint of a ROS run (its bag) left the zone."""
    import rosbag

    from quadrivio_description.frames import yaw_from_quaternion

    with rosbag.Bag(os.path.join(out, "run.bag")) as bag:
        poses = [(m.pose.pose.position.x, m.pose.pose.position.y,
                  yaw_from_quaternion(m.pose.pose.orientation.x, m.pose.pose.orientation.y,
                                      m.pose.pose.orientation.z, m.pose.pose.orientation.w))
                 for _, m, _ in bag.read_messages(topics=["/ground_truth/odom"])]
    return footprint_left(zone, poses)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--speeds", default="2,3")
    ap.add_argument("--runner", choices=("in_process", "ros"), default="in_process",
                    help="how the outcome runs go: one process each (default) or the ROS stack")
    ap.add_argument("--workers", type=int, default=2, help="in process: parallel runs")
    ap.add_argument("--latency-seeds", type=int, default=2,
                    help="ROS runs at factor 1 per speed of dog_runs_out and orchard_crossing (latency)")
    ap.add_argument("--rtf", type=float, default=2.0, help="--runner ros: the outcome runs' factor")
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
    from quadrivio.scenario import load_scenario

    zone = load_scenario("zone_edge").data["guard"]["zone"]
    jobs = []
    for name in names:
        for speed in speeds:
            path = variant(name, speed, args.out)
            for seed in range(args.seeds):
                out = os.path.join(args.out, f"{name}_{speed:g}_s{seed}")
                jobs.append((name, speed, seed, path, out))
    total = len(jobs)

    def report(k, name, speed, seed, m):
        print(f"[bench obstacles] {k}/{total} {name} {speed:g} m/s seed {seed}: "
              f"{'FAILED ' + str(m.get('error', '')) if m.get('failed') else 'completed' if m.get('completed') else 'not completed'}, "
              f"collisions {m.get('collisions')}, clearance {m.get('min_clearance_m')}, "
              f"stops {m.get('protective_stops')} (false {m.get('false_stops')}), "
              f"{time.monotonic() - t_start:.0f} s", flush=True)

    if args.runner == "in_process":
        import multiprocessing

        with multiprocessing.get_context("spawn").Pool(args.workers, maxtasksperchild=4) as pool:
            work = [(path, seed, out, zone if name == "zone_edge" else None) for name, speed, seed, path, out in jobs]
            for k, m in enumerate(pool.imap(run_in_process, work), 1):
                name, speed, seed = jobs[k - 1][:3]
                m.update(scenario=name, speed=speed, seed=seed)
                runs.append(m)
                report(k, name, speed, seed, m)
    else:
        for k, (name, speed, seed, path, out) in enumerate(jobs, 1):
            m = run(path, seed, out, args.rtf, extra=["--guard", args.guard])
            m.update(scenario=name, speed=speed, seed=seed)
            if name == "zone_edge" and not m.get("failed"):
                m["zone_exit"] = zone_exit(out, zone)
            runs.append(m)
            report(k, name, speed, seed, m)
    # the stop latency through the topics: ROS runs at factor 1
    latency_runs = []
    if args.latency_seeds > 0:
        for name in LATENCY:  # where protective stops happen (the person on the path slows, it does not stop)
            if name not in names:
                continue
            for speed in speeds:
                for seed in range(args.latency_seeds):
                    out = os.path.join(args.out, f"latency_{name}_{speed:g}_s{seed}")
                    m = run(variant(name, speed, args.out), seed, out, 1.0, extra=["--guard", args.guard])
                    latency_runs.append(m)
                    print(f"[bench obstacles] latency run {name} {speed:g} m/s seed {seed}: "
                          f"{'FAILED' if m.get('failed') else m.get('stop_latencies_ms')}", flush=True)
    ok = [r for r in runs if not r.get("failed")]
    result = {"machine": machine(), "seeds": args.seeds, "speeds": speeds, "runner": args.runner,
              "rtf": args.rtf if args.runner == "ros" else None, "guard": args.guard, "runs": len(runs),
              "runs_failed": len(runs) - len(ok), "wall_s": time.monotonic() - t_start}
    result["obstacle_collisions"] = int(sum(r.get("collisions") or 0 for r in ok))
    clear = [r["min_clearance_m"] for r in ok if r["scenario"] in WITH and r.get("min_clearance_m") is not None]
    result["obstacle_min_clearance_m"] = float(min(clear)) if clear else None
    result["obstacle_false_stops"] = int(sum(r.get("false_stops") or 0 for r in ok if r["scenario"] in WITHOUT))
    result["obstacle_false_stops_all"] = int(sum(r.get("false_stops") or 0 for r in ok))
    result["obstacle_protective_stops"] = int(sum(r.get("protective_stops") or 0 for r in ok))
    result["obstacle_anticipated_stops"] = int(sum(r.get("anticipated_stops") or 0 for r in ok))
    lat_from = [r for r in latency_runs if not r.get("failed")] if args.runner == "in_process" else ok
    lat = [x for r in lat_from for x in (r.get("stop_latencies_ms") or [])]
    result["obstacle_stop_latency_p99_ms"] = float(np.percentile(lat, 99)) if lat else None
    result["obstacle_stop_latency_max_ms"] = float(max(lat)) if lat else None
    result["obstacle_stop_latency_stops"] = len(lat)
    result["obstacle_stop_latency_rtf"] = 1.0 if args.runner == "in_process" else args.rtf
    blocked = [r for r in runs if r["scenario"] == "orchard_blocked"]
    if blocked:
        result["obstacle_replan_completed"] = float(np.mean([bool(r.get("completed")) for r in blocked]))
    zoned = [r for r in ok if r["scenario"] == "zone_edge"]
    if zoned:
        result["zone_exits"] = int(sum(bool(r.get("zone_exit")) for r in zoned))
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
              "anticipated_stops": int(sum(r.get("anticipated_stops") or 0 for r in rs)),
              "fault_stops": int(sum(r.get("fault_stops") or 0 for r in rs)),
              "time_blocked_s_mean": float(np.mean([r.get("time_blocked_s") or 0.0 for r in rs])),
              "xte_max_m": max((r["xte_max_m"] for r in rs if r.get("xte_max_m") is not None), default=None)}
        for key, rs in per.items()}
    # the guard's CPU and the layer's update time, from a factor-1 run
    if "person_on_path" in names:
        out = os.path.join(args.out, "cpu_person_on_path")
        floor = {}
        m = run(variant("person_on_path", 2.0, args.out), 1, out, 1.0, cpu_node="guard", floor=floor)
        if not m.get("failed") and m.get("cpu", {}).get("cpu_s") is not None:
            result["guard_cpu_frac"] = m["cpu"]["cpu_s"] / m["sim_duration_s"]
            # the same run's guard_inputs_sink: roscpp's delivery of the guard's inputs, no work
            if floor.get("cpu_s") and len(floor.get("samples", [])) >= 10:
                # the guard's CPU over the sink's window (it starts once the guard runs): a ratio
                gt, gc = np.array(m["cpu"]["samples"]).T
                (t0, c0), (t1, c1) = floor["samples"][0], floor["samples"][-1]
                ratio = (c1 - c0) / (np.interp(t1, gt, gc) - np.interp(t0, gt, gc))
                result["guard_cpu_floor_frac"] = ratio * result["guard_cpu_frac"]
                result["guard_cpu_floor_received"] = floor.get("received", "")
                print(f"[bench obstacles] the guard's inputs alone (guard_inputs_sink, the same run): "
                      f"{result['guard_cpu_floor_frac']:.4f} CPU s per simulated s; {floor.get('received')}",
                      flush=True)
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
    # A partial run (some scenarios, fewer seeds or other speeds) must not stand in for the
    # benchmark's figures: it writes obstacles_partial.json beside them
    partial = bool(args.only) or args.seeds < 10 or sorted(speeds) != [2.0, 3.0] or args.latency_seeds < 2
    name = "obstacles_partial" if partial else "obstacles"
    if partial:
        result["partial"] = {"only": args.only, "seeds": args.seeds, "speeds": speeds,
                             "latency_seeds": args.latency_seeds}
        print("[bench obstacles] a partial run (--only, --seeds < 10, --speeds other than 2,3 or "
              "--latency-seeds < 2): its figures go to obstacles_partial.json, not obstacles.json", flush=True)
    write_result(name, result)
    table = os.path.join(RESULTS, f"{name}.md")
    lines = ["| scenario | runs | completed | collisions | min clearance [m] | protective stops | false | "
             "anticipated | fail-safe | blocked mean [s] |\n|---|---|---|---|---|---|---|---|---|---|\n"]
    for key, row in result["per_scenario"].items():
        mc = row["min_clearance_m"]
        lines.append(f"| {key} | {row['runs']} | {row['completed']:.2f} | {row['collisions']} | "
                     f"{'' if mc is None else f'{mc:.2f}'} | {row['protective_stops']} | {row['false_stops']} | "
                     f"{row['anticipated_stops']} | {row['fault_stops']} | {row['time_blocked_s_mean']:.1f} |\n")
    atomic_write(table, "".join(lines))  # never a half-written table


if __name__ == "__main__":
    main()
