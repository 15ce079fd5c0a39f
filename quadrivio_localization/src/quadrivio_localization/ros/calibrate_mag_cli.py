"""``rosrun quadrivio_localization calibrate_mag BAG --out FILE``: the magnetometer's hard
and soft iron from a recorded drive, for the localization's priors.

Drive one full circle each way, slowly, on level ground, recording ``/imu/mag``,
``/imu/data`` and ``/vehicle/state`` (a figure eight does it). The tool levels the
readings exactly as the smoother does (:class:`quadrivio_localization.leveling.Leveller`,
with the vehicle's mounts and the wheel speed for the turn's acceleration), fits the
ellipse (:mod:`quadrivio_localization.mag_calibration`) against the site's horizontal
field, and writes FILE: a parameter file for the localization node
(``roslaunch ... mag_calibration:=FILE``), with a plot next to it. Nothing is written
when the bag cannot give a calibration; the message says what was missing.
"""

from __future__ import annotations

import argparse
import datetime as dt
import math
import os
import sys
from typing import List, Tuple

import numpy as np
import yaml

from quadrivio_config import ConfigError
from quadrivio_recordings.clocks import clock_warnings
from quadrivio_recordings.progress import BagProgress
from quadrivio_recordings.ros.bag import open_bag, read_messages
from quadrivio_description.site import load_site
from quadrivio_description.vehicle import load_vehicle
from quadrivio_runtime.files import atomic_path, atomic_write

from ..leveling import Leveller
from .. import sanity
from ..mag_calibration import MagCalibrationError, MagFit, MagFitParams, fit

SANITY_SAMPLES = 2000  # readings of each kind the unit checks look at (the bag's first)

UT = 1e6


def read_levelled(path: str, mag_topic: str, imu_topic: str, state_topic: str, vehicle, tilt_tau: float,
                  min_speed: float, period: float, imap=None) -> Tuple[np.ndarray, dict]:
    """Levelled horizontal readings [uT], averaged over ``period`` s, taken while moving.
    ``imap``: an import mapping (its topics and conversions replace the three topics)."""
    import rosbag

    if imap is not None:
        t = imap.topics()
        mag_topic, imu_topic, state_topic = t.get("mag", mag_topic), t.get("imu", imu_topic), t.get("state", "")
        role_of = {mag_topic: "mag", imu_topic: "imu", state_topic: "state"}

    bag = open_bag(path, MagCalibrationError)
    with bag:
        have = bag.get_type_and_topic_info().topics
        for role, topic in (("magnetometer", mag_topic), ("IMU", imu_topic)):
            if topic not in have:
                raise MagCalibrationError(f"{path} has no {role} topic {topic}; its topics: {', '.join(sorted(have))}")
        use_state = state_topic in have
        leveller = Leveller(vehicle, tilt_tau)
        counts = {"mag": 0, "imu": 0, "state": 0, "used": 0, "bad": 0}
        strengths: list = []  # [T] the first readings' field strengths, for the unit check
        forces: list = []  # [m/s^2] the first IMU readings' specific force
        speed = 0.0
        bins: dict = {}
        topics = [mag_topic, imu_topic] + ([state_topic] if use_state else [])
        offsets: dict = {}  # header stamp less recording time, per topic (one clock for all?)
        progress = BagProgress.of_bag("calibrate_mag", os.path.basename(path), bag)
        try:
            for topic, msg, t_recv in read_messages(bag, path, topics, error=MagCalibrationError):
                progress.update(t_recv.to_sec())
                if imap is not None:
                    msg = imap.convert(role_of[topic], msg, t_recv)  # a ConfigError names a missing field
                try:
                    t = msg.header.stamp.to_sec()
                    if len(offsets.setdefault(topic, [])) < SANITY_SAMPLES:
                        offsets[topic].append(t - t_recv.to_sec())
                    if topic == state_topic:
                        speed = float(msg.wheel_speed)
                        leveller.add_speed(t, speed)
                        counts["state"] += 1
                    elif topic == imu_topic:
                        a, w = msg.linear_acceleration, msg.angular_velocity
                        f, g = (a.x, a.y, a.z), (w.x, w.y, w.z)
                        if not all(math.isfinite(v) for v in f + g):
                            counts["bad"] += 1
                            continue
                        leveller.add_imu(t, f, g)
                        counts["imu"] += 1
                        if len(forces) < SANITY_SAMPLES:
                            forces.append(math.sqrt(f[0] ** 2 + f[1] ** 2 + f[2] ** 2))
                    else:
                        mf = msg.magnetic_field
                        m = (mf.x, mf.y, mf.z)
                        counts["mag"] += 1
                        if len(strengths) < SANITY_SAMPLES:
                            strengths.append(math.sqrt(m[0] ** 2 + m[1] ** 2 + m[2] ** 2))
                        if not all(math.isfinite(v) for v in m) or leveller.t is None:
                            counts["bad"] += 1
                            continue
                        if use_state and abs(speed) < min_speed:
                            continue
                        mx, my = leveller.level_mag(m)
                        bins.setdefault(int(t // period), []).append((mx * UT, my * UT))
                        counts["used"] += 1
                except AttributeError as exc:
                    raise MagCalibrationError(f"{topic}: {msg._type} lacks a field the tool reads ({exc})") from exc
        except rosbag.ROSBagException as exc:
            raise MagCalibrationError(f"{path}: corrupt bag ({exc})") from exc
    counts["moving_filter"] = use_state
    # the IMU levels the magnetometer at its stamps: one clock for both, or a levelling of other moments
    counts["sanity"] = [("error", w) for w in clock_warnings(offsets)] + sanity.check_all(strengths, forces)
    m = np.array([np.mean(v, axis=0) for _, v in sorted(bins.items())]) if bins else np.zeros((0, 2))
    return m, counts


def _plot(path: str, m: np.ndarray, r: MagFit, h_en) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    theta = np.linspace(-math.pi, math.pi, 361)
    e = r.predict(theta, h_en)
    fig, ax = plt.subplots(1, 2, figsize=(11, 5))
    ax[0].plot(m[:, 0], m[:, 1], ".", ms=3, label=f"levelled readings ({len(m)})")
    ax[0].plot(e[:, 0], e[:, 1], "r-", label="fitted model")
    ax[0].plot(*r.hard_iron, "r+", ms=12, label="hard iron")
    ax[0].add_patch(plt.Circle((0, 0), r.field, fill=False, ls="--", color="gray", label="Earth's field, undistorted"))
    ax[0].set_aspect("equal")
    ax[0].set_xlabel("m_x [uT]")
    ax[0].set_ylabel("m_y [uT]")
    ax[0].legend(fontsize=8, loc="upper left", framealpha=0.8)
    ax[0].grid(alpha=0.3)
    sx, sy, sxy = r.soft_iron
    b = np.linalg.solve(np.array([[sx, sxy], [sxy, sy]]), (m - np.array(r.hard_iron)).T).T
    ax[1].plot(np.degrees(np.arctan2(b[:, 1], b[:, 0])), np.hypot(b[:, 0], b[:, 1]) - r.field, ".", ms=3)
    ax[1].axhline(0.0, color="k", lw=0.8)
    ax[1].set_xlabel("direction of the corrected reading [deg]")
    ax[1].set_ylabel("|corrected| - |h| [uT]")
    ax[1].set_title(f"RMS {r.rms:.2f} uT, coverage {r.coverage:.0f} deg")
    ax[1].grid(alpha=0.3)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)


def run(args) -> int:
    vehicle = load_vehicle(args.vehicle_file)
    site = load_site(args.site_file)
    h = site.magnetic_field.enu()
    h_en = (h[0] * UT, h[1] * UT)
    field = math.hypot(*h_en)
    p = MagFitParams(min_coverage=args.min_coverage)
    print(f"[calibrate_mag] reading {args.bag}", flush=True)
    imap = None
    if args.map:
        from quadrivio_recordings.ros import import_map

        imap = import_map.load(args.map)  # a ConfigError names the file and the key
    m, counts = read_levelled(args.bag, args.mag_topic, args.imu_topic, args.state_topic, vehicle, args.tilt_tau,
                              args.min_speed, args.period, imap)
    print(f"[calibrate_mag] {counts['mag']} magnetometer and {counts['imu']} IMU messages, {counts['state']} "
          f"vehicle states; {counts['used']} readings used" + (" (while moving)" if counts["moving_filter"] else "") +
          (f", {counts['bad']} unusable" if counts["bad"] else ""), flush=True)
    for level, text in counts["sanity"]:
        print(f"[calibrate_mag] WARNING: {text}", file=sys.stderr, flush=True)
    error = sanity.first_error(counts["sanity"])
    if error:  # a fit to a field 10^4 off would only fail later, far from the cause
        raise MagCalibrationError(error)
    r = fit(m, field, p)
    source = f"calibrate_mag {os.path.basename(args.bag)} {dt.date.today().isoformat()}"
    data = r.as_priors(source)
    header = (f"# Magnetometer calibration for quadrivio_localization (load into the localization node;\n"
              f"# roslaunch quadrivio sim.launch / real.launch mag_calibration:=THIS_FILE).\n"
              f"# Written by: rosrun quadrivio_localization calibrate_mag {args.bag} --out {args.out}\n"
              f"# Fit: {r.samples} averaged readings, heading coverage {r.coverage:.0f} deg, RMS {r.rms:.3f} uT,\n"
              f"# horizontal field {field:.2f} uT (site file). Sigmas: {p.sigma_scale:g} x the fit's standard errors.\n")
    out_dir = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(out_dir, exist_ok=True)
    text = header + yaml.safe_dump(data, default_flow_style=None, sort_keys=False)
    plot = os.path.splitext(args.out)[0] + ".png"
    _plot(plot, m, r, h_en)
    atomic_write(args.out, text)
    print(f"[calibrate_mag] hard iron ({r.hard_iron[0]:.2f}, {r.hard_iron[1]:.2f}) +- {r.hard_iron_sigma:.2f} uT, "
          f"soft iron xx {r.soft_iron[0]:.4f} yy {r.soft_iron[1]:.4f} xy {r.soft_iron[2]:.4f}; "
          f"RMS {r.rms:.2f} uT over {r.coverage:.0f} deg of heading")
    print(f"[calibrate_mag] wrote {args.out} and {plot}")
    return 0


def parse(argv: List[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="calibrate_mag", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", help="recorded drive through every heading (a figure eight, or circles each way)")
    ap.add_argument("--out", required=True, help="YAML to write (a plot is written next to it as .png)")
    ap.add_argument("--mag-topic", default="/imu/mag", help="sensor_msgs/MagneticField (default %(default)s)")
    ap.add_argument("--imu-topic", default="/imu/data", help="sensor_msgs/Imu, for roll and pitch (default %(default)s)")
    ap.add_argument("--state-topic", default="/vehicle/state",
                    help="quadrivio_plc/VehicleState: wheel speed, for the turn's acceleration and to use only "
                         "readings taken while moving (optional; default %(default)s)")
    ap.add_argument("--map", default="", metavar="YAML",
                    help="import mapping of a recording made with other drivers (its mag, imu and state sections "
                         "replace the topic options; quadrivio_recordings.ros.import_map)")
    ap.add_argument("--min-speed", type=float, default=0.3, help="[m/s] use readings above this speed (%(default)s)")
    ap.add_argument("--period", type=float, default=0.1, help="[s] readings are averaged over this (%(default)s)")
    ap.add_argument("--tilt-tau", type=float, default=1.0, help="[s] roll/pitch low-pass, as the smoother (%(default)s)")
    ap.add_argument("--min-coverage", type=float, default=300.0, help="[deg] heading span needed (%(default)s)")
    ap.add_argument("--vehicle-file", default="", help="vehicle.yaml (mounts); default quadrivio_description's")
    ap.add_argument("--site-file", default="", help="site.yaml (Earth's field); default quadrivio_description's")
    return ap.parse_args(argv)


def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    try:
        return run(args)
    except (MagCalibrationError, ConfigError) as exc:
        print(f"calibrate_mag: {exc}; nothing written", file=sys.stderr)
        return 2
