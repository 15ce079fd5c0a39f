"""``rosrun quadrivio_sim calibrate BAG --out DIR``: identify the simulator's actuator
loops from a recording of a vehicle, or replay a recording through the simulator.

From a bag with the setpoints sent to a vehicle and its measured handlebar angle and
speed, the tool fits the handlebar and speed loops (:mod:`quadrivio_sim.calibration`),
replays the recorded setpoints through the full simulator with the result (the
paper's own procedure, section 3.2), and writes into DIR:

* ``actuators.yaml`` -- the loops for the simulator (``simulator ~actuators_file``), the
  recorded vehicle's step responses as references;
* ``calibration.json`` -- identified values and standard errors, RMS errors of the fit and
  of the full-simulator replay, delay / rise time / overshoot measured and simulated;
* ``handlebar.png``, ``speed.png`` -- measured against simulated responses (Fig. 4).

``--replay`` skips the identification and compares the simulator (``--actuators``)
with the recording. Topic names and field paths are options (or ``--config`` YAML),
so recordings from other stacks work: the bag's own message definitions are used to
read it, no generated message classes are needed. Output is written to a temporary
folder and moved into place at the end: a failure leaves nothing half-done.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Dict, List, Optional, Tuple

import numpy as np
import yaml

from quadrivio_config import ConfigError, from_mapping, load_yaml, param, to_mapping
from quadrivio_recordings.ros import import_map
from quadrivio_recordings.clocks import clock_warnings
from quadrivio_recordings.progress import BagProgress
from quadrivio_recordings.ros.bag import open_bag, read_messages
from quadrivio_recordings.ros.import_map import get_field
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import load_vehicle

from ..actuators import ActuatorParams
from ..calibration import (CalibrationError, Series, apply_fits, find_steps, identify_handlebar, identify_speed,
                           make_series, mean_metrics, recording_warnings, reference_from, rms, step_metrics)
from ..paths import package_file
from ..script import ScriptRow, SetpointScript
from ..simulator import SimParams, Simulator


@dataclass(frozen=True)
class TopicSpec:
    topic: str = param(doc="topic in the bag")
    speed: str = param("speed", doc="field path of the speed [m/s] ('' if absent)")
    handlebar: str = param("handlebar", doc="field path of the handlebar / steering angle [rad]")
    brake: str = param("", doc="field path of the brake [0..1] ('' if absent)")


@dataclass(frozen=True)
class BagSpec:
    setpoint: TopicSpec = param(TopicSpec("/vehicle/setpoint/auto", "speed", "handlebar", "brake"))
    measurement: TopicSpec = param(TopicSpec("/vehicle/state", "wheel_speed", "handlebar", ""))
    stamp: str = param("auto", choices=("auto", "header", "bag"),
                       doc="time of a message: header.stamp, the bag's, or auto: the header's where a message has "
                           "one that is set, else the bag's (unstamped setpoints need no flag)")


# ---------------------------------------------------------------- reading

def _field(msg, path: str, topic: str) -> float:
    return float(get_field(msg, path, topic, "the calibration", CalibrationError))


CLOCK_SAMPLES = 500  # messages of each topic whose stamps are compared with their recording times


def _offset(offsets: Dict[str, List[float]], topic: str, t: float, t_bag) -> None:
    seen = offsets.setdefault(topic, [])
    if len(seen) < CLOCK_SAMPLES:
        seen.append(t - t_bag.to_sec())


def _add(rec: Dict[str, List[float]], topic: str, t: float, values: Dict[str, float], unusable: Dict[str, int]) -> None:
    """Append one message's time and values, unless one of them is not finite (counted)."""
    if not all(math.isfinite(v) for v in values.values()) or not math.isfinite(t):
        unusable[topic] = unusable.get(topic, 0) + 1
        return
    rec.setdefault("t", []).append(t)
    for name, value in values.items():
        rec.setdefault(name, []).append(value)


def spec_from_map(imap) -> BagSpec:
    """The topics of an import mapping's ``setpoint`` and ``state`` sections (its fields and
    scales are read through the mapping itself)."""
    for role in ("setpoint", "state"):
        if role not in imap.sections:
            raise CalibrationError(f"{imap.path}: no '{role}' section, and calibrate needs it (the setpoints sent "
                                   "and the measured wheel speed and handlebar)")
    return BagSpec(TopicSpec(imap.sections["setpoint"].topic), TopicSpec(imap.sections["state"].topic))


def read_bag(path: str, spec: BagSpec, imap=None) -> Dict[str, Dict[str, np.ndarray]]:
    """Arrays ``{"setpoint": {"t", "speed", "handlebar", "brake"}, "measurement": {...}}``;
    with ``imap`` (an import mapping) its setpoint and state sections say what is read."""
    import rosbag

    bag = open_bag(path, CalibrationError)
    with bag:
        topics = bag.get_type_and_topic_info().topics
        for role in ("setpoint", "measurement"):
            t = getattr(spec, role).topic
            if t not in topics:
                have = ", ".join(f"{name} ({info.msg_type})" for name, info in sorted(topics.items())) or "none"
                raise CalibrationError(f"{path} has no {role} topic {t}"
                                       f"{f' ({imap.path})' if imap is not None else ''}; its topics: {have}")
        out: Dict[str, Dict[str, List[float]]] = {"setpoint": {}, "measurement": {}}
        unusable: Dict[str, int] = {}
        bag_timed: Dict[str, int] = {}
        offsets: Dict[str, List[float]] = {}  # header stamp less recording time, per topic
        by_topic = {spec.setpoint.topic: ("setpoint", spec.setpoint), spec.measurement.topic: ("measurement", spec.measurement)}
        progress = BagProgress.of_bag("calibrate", os.path.basename(path), bag)
        try:
            for topic, msg, t_bag in read_messages(bag, path, list(by_topic), error=CalibrationError):
                progress.update(t_bag.to_sec())
                role, ts = by_topic[topic]
                rec = out[role]
                if imap is not None:
                    section = "setpoint" if role == "setpoint" else "state"
                    t = imap.stamp(section, msg, t_bag)
                    values = {("speed" if k == "wheel_speed" else k): v for k, v in imap.scalars(section, msg).items()}
                    _add(rec, topic, t, values, unusable)
                    _offset(offsets, topic, t, t_bag)
                    continue
                header = getattr(msg, "header", None)
                if spec.stamp == "header":
                    if header is None:
                        raise CalibrationError(f"{topic}: {msg._type} has no header; use --stamp bag (or auto)")
                    t = header.stamp.to_sec()
                elif spec.stamp == "auto" and header is not None and not header.stamp.is_zero():
                    t = header.stamp.to_sec()
                else:  # bag, or auto without a header stamp: when the recorder got it
                    t = t_bag.to_sec()
                    if spec.stamp == "auto":
                        bag_timed[topic] = bag_timed.get(topic, 0) + 1
                values = {name: _field(msg, getattr(ts, name), topic) for name in ("speed", "handlebar", "brake")
                          if getattr(ts, name)}
                _add(rec, topic, t, values, unusable)
                _offset(offsets, topic, t, t_bag)
        except rosbag.ROSBagException as exc:
            raise CalibrationError(f"{path}: corrupt bag ({exc})") from exc
    clocks = clock_warnings(offsets)  # a dead time fitted across two clocks would be their offset
    if clocks:
        raise CalibrationError(clocks[0] if imap is not None else
                               clocks[0].replace("an import mapping's `stamp: receipt`", "--stamp bag"))
    for topic, n in unusable.items():
        print(f"[calibrate] {topic}: {n} message(s) with a value that is not a finite number skipped (e.g. the "
              "PLCClient's states while it has no PLC session)", file=sys.stderr)
    for topic, n in bag_timed.items():
        print(f"[calibrate] {topic}: {n} message(s) without a header stamp timed by the bag's record time "
              "(its transport delay counts as dead time)", file=sys.stderr)
    arrays = {}
    for role, rec in out.items():
        if len(rec.get("t", [])) < 20:
            raise CalibrationError(f"{path}: only {len(rec.get('t', []))} {role} messages on "
                                   f"{getattr(spec, role).topic}")
        order = np.argsort(rec["t"], kind="stable")
        arrays[role] = {k: np.asarray(v)[order] for k, v in rec.items()}
    return arrays


def series_for(data, loop: str, dt_cycle: float) -> Series:
    sp, ms = data["setpoint"], data["measurement"]
    for role, rec in (("setpoint", sp), ("measurement", ms)):
        if loop not in rec:
            raise CalibrationError(f"no {loop} field configured for the {role} topic: the {loop} loop needs both")
    brake = sp.get("brake") if loop == "speed" else None
    return make_series(sp["t"], sp[loop], ms["t"], ms[loop], dt_cycle, brake)


# --------------------------------------------------------------- replaying

def replay(data, actuators: ActuatorParams, sim_params: SimParams) -> Dict[str, Tuple[np.ndarray, np.ndarray]]:
    """Feed the recorded setpoints into the full simulator: ``{loop: (t, simulated)}``."""
    vehicle = load_vehicle()
    sp = data["setpoint"]
    t0 = float(sp["t"][0])
    n = len(sp["t"])
    rows = [ScriptRow(float(sp["t"][k]) - t0, float(sp.get("speed", np.zeros(n))[k]),
                      float(sp.get("handlebar", np.zeros(n))[k]), float(sp.get("brake", np.zeros(n))[k]))
            for k in range(n)]
    sim = Simulator(sim_params, vehicle, actuators, build_urdf(vehicle))
    sim.script = SetpointScript(rows, "the bag's setpoints")
    ts, hs, vs = [], [], []
    end = rows[-1].t
    try:
        while sim.t <= end:
            cycle = sim.steps % sim.cycle_steps == 0
            t_cycle = sim.t
            sim.step()
            if cycle:  # what the PLC computed and measured at the start of this cycle
                ts.append(t_cycle + t0)
                hs.append(sim.control.handlebar.angle)
                vs.append(sim.control.speed_measured)
    finally:
        sim.close()
    t = np.asarray(ts)
    return {"handlebar": (t, np.asarray(hs)), "speed": (t, np.asarray(vs))}


# ------------------------------------------------------------------ output

def _plot(path: str, loop: str, s: Series, sim_t: np.ndarray, sim_y: np.ndarray, fit_y: Optional[np.ndarray]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    unit = "rad" if loop == "handlebar" else "m/s"
    fig, ax = plt.subplots(figsize=(10, 4.2))
    t0 = s.t[0]
    ax.plot(s.t - t0, s.setpoint, "k--", lw=1.0, label="setpoint")
    ax.plot(s.t - t0, s.measured, color="tab:blue", lw=1.2, label="measured (vehicle)")
    ax.plot(sim_t - t0, sim_y, color="tab:red", lw=1.2, label="simulated (full simulator)")
    if fit_y is not None:
        ax.plot(s.t - t0, fit_y, color="tab:orange", lw=0.8, ls=":", label="identified loop model")
    ax.set_xlabel("time [s]")
    ax.set_ylabel(f"{loop} [{unit}]")
    ax.set_title(f"{loop} step responses: vehicle vs simulator (cf. paper Fig. 4)")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _metrics_dict(m) -> Optional[Dict[str, float]]:
    return None if m is None else {k: round(v, 4) for k, v in dataclasses.asdict(m).items()}


def run(args) -> int:
    try:
        if os.path.exists(args.out) and not os.path.isdir(args.out):
            raise CalibrationError(f"--out {args.out} is a file, not a folder")
        imap = None
        if args.map:
            if args.config or args.setpoint_topic or args.measurement_topic or args.setpoint_fields or \
                    args.measurement_fields or args.stamp:
                raise CalibrationError("--map says the topics, fields and stamps: it replaces --config, "
                                       "--setpoint-*, --measurement-* and --stamp")
            imap = import_map.load(args.map)
            spec = spec_from_map(imap)
        else:
            spec = from_mapping(BagSpec, load_yaml(args.config), args.config) if args.config else BagSpec()
            spec = _apply_cli_topics(spec, args)
        base_file = args.actuators or package_file("config", "actuators.yaml")
        base = from_mapping(ActuatorParams, load_yaml(base_file), base_file)
        sim_params = from_mapping(SimParams, load_yaml(package_file("config", "sim.yaml")), "sim.yaml")
        vehicle = load_vehicle()
        print(f"[calibrate] reading {args.bag}", flush=True)
        data = read_bag(args.bag, spec, imap)
        dt_cycle = sim_params.plc.cycle
        loops = [x for x in args.loops.split(",") if x]
        series = {loop: series_for(data, loop, dt_cycle) for loop in loops}
        report: Dict = {"bag": os.path.abspath(args.bag), "mode": "replay" if args.replay else "identify",
                        "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds"), "loops": {},
                        "warnings": []}
        for loop in loops:
            for warning in recording_warnings(loop, series[loop], vehicle):
                print(f"[calibrate] WARNING: {warning}", file=sys.stderr, flush=True)
                report["warnings"].append(warning)
        fits, fit_curves = [], {}
        if not args.replay:
            from ..calibration import simulate_handlebar, simulate_speed
            for loop in loops:
                print(f"[calibrate] identifying the {loop} loop from {series[loop].t[-1] - series[loop].t[0]:.1f} s "
                      f"of data ...", flush=True)
                if loop == "handlebar":
                    f = identify_handlebar(series[loop], vehicle, base.handlebar)
                else:
                    f = identify_speed(series[loop], vehicle, base.speed, sim_params.terrain.rolling_resistance)
                fits.append(f)
            refs = {}
            for loop in loops:
                s = series[loop]
                steps = find_steps(s, 0.05 if loop == "handlebar" else 0.5, 1.0)
                refs[loop] = reference_from(steps, [step_metrics(s.t, s.measured, st) for st in steps])
            result = apply_fits(base, fits, refs)
            for loop, f in zip(loops, fits):
                s = series[loop]
                fit_curves[loop] = (simulate_handlebar(result.handlebar, vehicle, s) if loop == "handlebar" else
                                    simulate_speed(result.speed, vehicle, sim_params.terrain.rolling_resistance, s))
        else:
            result = base
        print("[calibrate] replaying the recorded setpoints through the full simulator ...", flush=True)
        simulated = replay(data, result, sim_params)
        with tempfile.TemporaryDirectory(prefix=".calibrate-", dir=os.path.dirname(os.path.abspath(args.out)) or ".") as tmp:
            for loop in loops:
                s = series[loop]
                t_sim, y_sim = simulated[loop]
                y_sim_grid = np.interp(s.t, t_sim, y_sim)
                steps = find_steps(s, 0.05 if loop == "handlebar" else 0.5, 1.0)
                entry = {
                    "replay_rms": round(rms(y_sim_grid, s.measured), 5),
                    "measured": _metrics_dict(mean_metrics([step_metrics(s.t, s.measured, st) for st in steps])),
                    "simulated": _metrics_dict(mean_metrics([step_metrics(s.t, y_sim_grid, st) for st in steps])),
                    "steps": len(steps),
                }
                fit = next((f for f in fits if f.loop == loop), None)
                if fit is not None:
                    entry.update({"identified": {k: round(v, 6) for k, v in fit.values.items()},
                                  "std_errors": {k: round(v, 6) for k, v in fit.std_errors.items()},
                                  "fit_rms": round(fit.rms, 5), "noise_estimate": round(fit.noise, 5),
                                  "notes": fit.notes})
                report["loops"][loop] = entry
                _plot(os.path.join(tmp, f"{loop}.png"), loop, s, t_sim, y_sim, fit_curves.get(loop))
            if not args.replay:
                with open(os.path.join(tmp, "actuators.yaml"), "w") as fh:
                    fh.write(f"# Actuator loops identified by quadrivio_sim calibrate from {os.path.basename(args.bag)}\n"
                             f"# on {report['date']}; see calibration.json for errors and step metrics.\n"
                             f"# Use it with: roslaunch quadrivio sim.launch ... (simulator ~actuators_file)\n")
                    yaml.safe_dump(to_mapping(result), fh, sort_keys=False)
            with open(os.path.join(tmp, "calibration.json"), "w") as fh:
                json.dump(report, fh, indent=2)
            # Into the output folder file by file, each replaced atomically: files of
            # the folder that are not ours are left alone (it may be a user's folder).
            os.makedirs(args.out, exist_ok=True)
            for name in sorted(os.listdir(tmp)):
                os.replace(os.path.join(tmp, name), os.path.join(args.out, name))
    except (CalibrationError, ConfigError) as exc:
        print(f"calibrate: {exc}", file=sys.stderr)
        print("calibrate: nothing written", file=sys.stderr)
        return 2
    _print_summary(report)
    print(f"[calibrate] results in {args.out}", flush=True)
    return 0


def _apply_cli_topics(spec: BagSpec, args) -> BagSpec:
    def fields(ts: TopicSpec, topic: Optional[str], text: Optional[str]) -> TopicSpec:
        changes = {}
        if topic:
            changes["topic"] = topic
        for item in (text or "").split(","):
            if item:
                key, _, value = item.partition("=")
                if key not in ("speed", "handlebar", "brake"):
                    raise ConfigError(f"--*-fields: '{key}' is not one of speed, handlebar, brake")
                changes[key] = value
        return dataclasses.replace(ts, **changes)
    spec = dataclasses.replace(spec, setpoint=fields(spec.setpoint, args.setpoint_topic, args.setpoint_fields),
                               measurement=fields(spec.measurement, args.measurement_topic, args.measurement_fields))
    return dataclasses.replace(spec, stamp=args.stamp) if args.stamp else spec


def _print_summary(report) -> None:
    for loop, e in report["loops"].items():
        print(f"[calibrate] {loop}:")
        if "identified" in e:
            for k, v in e["identified"].items():
                print(f"    {k:14s} {v:10.4f}  +- {e['std_errors'].get(k, float('nan')):.4f}")
            print(f"    fit RMS {e['fit_rms']:.4f} (noise {e['noise_estimate']:.4f})")
        print(f"    full-simulator replay RMS {e['replay_rms']:.4f}")
        for which in ("measured", "simulated"):
            m = e[which]
            if m:
                print(f"    {which:9s}: delay {m['delay']:.3f} s, rise {m['rise_time']:.3f} s, "
                      f"overshoot {m['overshoot']:.1%}")


def main(argv: Optional[List[str]] = None) -> int:
    p = argparse.ArgumentParser(prog="calibrate", description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="bag with setpoints and measured responses")
    p.add_argument("--out", required=True, help="output folder: its actuators.yaml, calibration.json and plots are "
                                                "replaced, nothing else in it is touched")
    p.add_argument("--replay", action="store_true", help="compare the simulator with the recording, no fitting")
    p.add_argument("--actuators", default="", help="actuator YAML to start from / replay (default: the package's)")
    p.add_argument("--loops", default="handlebar,speed", help="which loops: handlebar,speed")
    p.add_argument("--config", default="", help="YAML of topics and fields (keys: setpoint, measurement, stamp)")
    p.add_argument("--map", default="", metavar="YAML",
                   help="import mapping of a recording made with other drivers (quadrivio_recordings.ros.import_map): "
                        "its setpoint and state sections, units and scales included; replaces --config and the "
                        "topic, field and stamp options")
    p.add_argument("--setpoint-topic", default="", help="default /vehicle/setpoint/auto")
    p.add_argument("--measurement-topic", default="", help="default /vehicle/state")
    p.add_argument("--setpoint-fields", default="", help="e.g. speed=speed,handlebar=steer,brake=brake")
    p.add_argument("--measurement-fields", default="", help="e.g. speed=speed,handlebar=steer")
    p.add_argument("--stamp", default="", choices=("", "auto", "header", "bag"),
                   help="message time: header.stamp, bag time, or auto (default: the header's where set, else the bag's)")
    args = p.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    return run(args)

