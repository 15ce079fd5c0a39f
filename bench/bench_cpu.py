"""Where every CPU second of the closed loop goes, per process, at real-time factors 1, 3
and 5 (issue 11).

The paper's figure eight (scenarios/figure_eight.yaml, its seed) run with ``rosrun
quadrivio experiment --rtf F``; while it runs, each process of the run (every node by its
``__name``, the recorder, roslaunch, the master, experiment itself) is sampled from
/proc every 0.25 s; its CPU time (user + system, all threads) from the moment the run
starts (experiment's "running": start-up, Python imports, is not the loop's cost) to its
end, over the run's simulated duration, is its cost in CPU seconds per simulated second. The achieved factor and the
tracking come from the run's metrics.json.

Writes bench/results/cpu.json (``cpu_per_sim_s``: factor -> process -> CPU s per sim s;
``sensors_cpu_per_sim_s_f1``: simulator plus every adapter at factor 1, in the closed loop) and cpu.md (the table).

Profiles: during the factor-1 run, the two Python processes that used the most CPU in its
first seconds are sampled by py-spy (requirements.txt; non-blocking, 100 Hz, 25 s, the
thread holding the GIL: a thread blocked in recv or select looks busy to py-spy otherwise,
and GTSAM and PyBullet keep the GIL while they compute): ``pyspy_<process>.svg`` (a
flame graph) and ``pyspy.md`` (each one's functions by their own samples and by the
samples under them, in % of the samples, where 100 % is the time it held the GIL).
"""
import collections
import json
import os
import re
import shutil
import subprocess
import sys
import threading
import time
from typing import Dict

from quadrivio_runtime.files import atomic_write

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import RESULTS, machine, write_result  # noqa: E402

SCENARIO = "figure_eight"
FACTORS = (1.0, 3.0, 5.0)
TICK = os.sysconf("SC_CLK_TCK")
ADAPTERS = ("sensor_adapters", "gps_adapter", "imu_adapter", "mag_adapter", "laser_front", "laser_rear", "camera_left", "camera_right")


def _name(args: str) -> str:
    m = re.search(r"__name:=(\S+)", args)
    if m:
        return m.group(1)
    for key, name in (("rosbag/record", "record"), ("bin/experiment", "experiment"), ("rosmaster", "rosmaster"),
                      ("roslaunch", "roslaunch"), ("rosout", "rosout")):
        if key in args:
            return name
    return ""


def _cpu(pid: str) -> float:
    with open(f"/proc/{pid}/stat") as fh:
        fields = fh.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / TICK  # utime, stime (fields 14, 15)


def run_processes():
    """``(pid, name)`` of every process of the run that :func:`_name` names, but this one."""
    me = os.getpid()
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == me:
            continue
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as fh:
                name = _name(fh.read().replace(b"\0", b" ").decode(errors="replace"))
        except OSError:
            continue  # gone
        if name:
            yield pid, name


def sample(stop: threading.Event, seen: Dict[str, tuple], running: threading.Event,
           base: Dict[str, float]) -> None:
    """Keep each run process's latest CPU time, ``seen``: pid -> (name, seconds), and in
    ``base`` each one's CPU time when the run started (start-up is not the loop's cost)."""
    while not stop.is_set():
        snap = running.is_set() and not base
        for pid, name in run_processes():
            try:
                seen[pid] = (name, _cpu(pid))
            except (OSError, IndexError, ValueError):
                continue
            if snap:
                base[pid] = seen[pid][1]
        if snap and not base:
            base["-"] = 0.0
        stop.wait(0.25)


PROFILE_AFTER, PROFILE_FOR = 8.0, 25  # [s wall] from the run's start; how long


def _python(pid: str) -> bool:
    try:
        with open(f"/proc/{pid}/cmdline", "rb") as fh:
            return b"python" in fh.read().split(b"\0")[0]
    except OSError:
        return False


def profile(seen: Dict[str, tuple], base: Dict[str, float], running: threading.Event, stop: threading.Event,
            done: Dict[str, str]) -> None:
    """py-spy on the two busiest Python processes (see the module docstring); ``done``:
    process name -> raw samples file."""
    spy = shutil.which("py-spy")
    if spy is None:
        print("[bench cpu] py-spy not found (pip install -r requirements.txt): no profiles", flush=True)
        return
    if not running.wait(120) or stop.wait(PROFILE_AFTER):
        return
    used = sorted(((cpu - base.get(pid, cpu), pid, name) for pid, (name, cpu) in list(seen.items())
                   if _python(pid)), reverse=True)[:2]
    procs = []
    for _, pid, name in used:
        raw = os.path.join(RESULTS, f".pyspy_{name}.txt")
        for fmt, path in (("flamegraph", os.path.join(RESULTS, f"pyspy_{name}.svg")), ("raw", raw)):
            procs.append(subprocess.Popen([spy, "record", "--pid", pid, "--duration", str(PROFILE_FOR), "--rate", "100",
                                           "--nonblocking", "--gil", "--format", fmt, "--output", path],
                                          stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True))
        done[name] = raw
    for p in procs:
        _, err = p.communicate()
        if p.returncode != 0:
            print(f"[bench cpu] py-spy failed: {err.strip().splitlines()[-1:] or p.returncode}", flush=True)


def summarise(raw: str, top: int = 12) -> str:
    """A py-spy raw file (``frame;frame;... count`` lines) as two Markdown lists: functions
    by their own samples, and by the samples in and under them."""
    own, under, total = collections.Counter(), collections.Counter(), 0
    with open(raw) as fh:
        for line in fh:
            stack, _, n = line.rstrip().rpartition(" ")
            if not stack or not n.isdigit():
                continue
            frames = [f for f in stack.split(";") if not f.startswith("thread (")]
            if not frames:
                continue
            total += int(n)
            own[frames[-1]] += int(n)
            for f in set(frames):
                under[f] += int(n)
    if not total:
        return "no samples\n"
    out = [f"{total} samples; own:"]
    out += [f"- {100 * c / total:.1f} % {f}" for f, c in own.most_common(top)]
    out.append("in and under:")
    out += [f"- {100 * c / total:.1f} % {f}" for f, c in under.most_common(top + 8) if not f.startswith("<module>")
            and "Thread._bootstrap" not in f][:top]
    return "\n".join(out) + "\n"


def run(rtf: float, profiles: Dict[str, str] = None) -> dict:
    out = os.path.join(RESULTS, f".cpu_rtf{rtf:g}")
    seen: Dict[str, tuple] = {}
    base: Dict[str, float] = {}
    stop, running = threading.Event(), threading.Event()
    th = threading.Thread(target=sample, args=(stop, seen, running, base), daemon=True)
    th.start()
    if profiles is not None:
        prof = threading.Thread(target=profile, args=(seen, base, running, stop, profiles), daemon=True)
        prof.start()
    t0 = time.monotonic()
    proc = subprocess.Popen(["rosrun", "quadrivio", "experiment", SCENARIO, "--rtf", str(rtf), "--out", out,
                             "--wall-timeout", "400"], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    tail = []
    for line in proc.stdout:  # "running (logs in ...)": the simulator was just unpaused
        tail = (tail + [line])[-40:]
        if "] running" in line:
            running.set()
    proc.wait()
    stop.set()
    th.join()
    if profiles is not None:
        prof.join()
    wall = time.monotonic() - t0
    try:
        with open(os.path.join(out, "metrics.json")) as fh:
            m = json.load(fh)
    except OSError:
        print("".join(tail), file=sys.stderr)
        raise SystemExit(f"[bench cpu] the factor-{rtf:g} run wrote no metrics")
    sim = m["sim_duration_s"]
    per: Dict[str, float] = {}
    for pid, (name, cpu) in seen.items():
        per[name] = per.get(name, 0.0) + cpu - base.get(pid, 0.0)
    per = {k: v / sim for k, v in sorted(per.items(), key=lambda kv: -kv[1])}
    print(f"[bench cpu] factor {rtf:g}: achieved {m['rtf']:.2f}, completed {m['completed']}, "
          f"total {sum(per.values()):.3f} CPU s per sim s; top: " +
          ", ".join(f"{k} {v:.3f}" for k, v in list(per.items())[:4]), flush=True)
    return {"per": per, "achieved_rtf": m["rtf"], "completed": bool(m["completed"]), "sim_s": sim, "wall_s": wall,
            "xte_rmse_m": m.get("xte_rmse_m"), "loc_rmse_m": m.get("loc_rmse_m")}


def table(runs: Dict[float, dict]) -> str:
    names = sorted({n for r in runs.values() for n in r["per"]}, key=lambda n: -runs[FACTORS[0]]["per"].get(n, 0.0))
    head = "| process | " + " | ".join(f"factor {f:g}" for f in runs) + " |"
    lines = [head, "|---|" + "---|" * len(runs)]
    for n in names:
        lines.append(f"| {n} | " + " | ".join(f"{r['per'].get(n, 0.0):.3f}" for r in runs.values()) + " |")
    lines.append("| **total** | " + " | ".join(f"**{sum(r['per'].values()):.3f}**" for r in runs.values()) + " |")
    lines.append("| achieved factor | " + " | ".join(f"{r['achieved_rtf']:.2f}" for r in runs.values()) + " |")
    lines.append("| completed | " + " | ".join("yes" if r["completed"] else "no" for r in runs.values()) + " |")
    return "\n".join(lines) + "\n"


def main():
    profiles: Dict[str, str] = {}
    runs = {f: run(f, profiles if f == FACTORS[0] else None) for f in FACTORS}
    one = runs[FACTORS[0]]["per"]
    result = {"scenario": f"{SCENARIO} (its seed)", "machine": machine(),
              "unit": "CPU seconds per simulated second, per process (all its threads)",
              "cpu_per_sim_s": {f"{f:g}": r["per"] for f, r in runs.items()},
              "sensors_cpu_per_sim_s_f1": one.get("simulator", 0.0) + sum(one.get(a, 0.0) for a in ADAPTERS)}
    for f, r in runs.items():
        for k in ("achieved_rtf", "completed", "xte_rmse_m", "loc_rmse_m", "wall_s"):
            v = r[k]
            result[f"f{f:g}_{k}"] = (1.0 if v else 0.0) if isinstance(v, bool) else v
    write_result("cpu", result)
    md = os.path.join(RESULTS, "cpu.md")
    atomic_write(md, table(runs))
    print(table(runs))
    if profiles:
        text = "".join(f"## {name} (py-spy, factor {FACTORS[0]:g})\n\n{summarise(raw)}\n"
                       for name, raw in profiles.items() if os.path.exists(raw))
        path = os.path.join(RESULTS, "pyspy.md")
        atomic_write(path, text)
        print(text)


if __name__ == "__main__":
    main()
