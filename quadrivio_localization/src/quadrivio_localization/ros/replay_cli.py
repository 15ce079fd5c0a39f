"""``rosrun quadrivio_localization replay BAG --out OUT.bag``: the smoother offline over a
recorded bag's sensor topics, as fast as it can, deterministically.

The bag's messages are taken in their recording order (the order the online node received
them) and fed to the same :class:`~quadrivio_localization.smoother.Localizer` through the
same conversions (:mod:`.messages`); the smoother is updated at every ``1 / rate`` tick of
the bag's clock between them, as the online node's timer would. Nothing depends on the
wall clock or the machine's speed: the same bag and parameters give the same OUT.bag,
message for message.

OUT.bag holds the bag's own messages (``--only-outputs``: none of them) with the recorded
``/localization/*`` topics and ``map -> odom`` transforms replaced by the replay's
``/localization/odom`` and ``/localization/calibration``: ``rosrun quadrivio analyze
OUT.bag`` then scores the replayed localization. Parameters: the node's
``config/localization.yaml``, then each ``--params`` file in order (a magnetometer
calibration from ``calibrate_mag``, a scenario's ``localization:`` section, your tuning).

Use it to tune the smoother on one recording, to compare parameter sets on the same data,
or to localize a bag from the vehicle recorded without the stack.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from typing import Any, Dict, Iterator, List, Tuple

from quadrivio_config import ConfigError, from_mapping, load_yaml
from quadrivio_description.paths import package_dir as _package_dir
from quadrivio_recordings.ros.bag import open_bag, read_messages
from quadrivio_description.site import load_site
from quadrivio_description.vehicle import load_vehicle
from quadrivio_recordings.clocks import clock_warnings
from quadrivio_runtime.files import atomic_path, atomic_write

from .. import sanity
from ..smoother import Estimate, Localizer, LocalizerParams

ROLES = ("gps", "imu", "mag", "state")


class ReplayError(Exception):
    """The bag or the parameters cannot give a replay; the message says why."""


def package_dir() -> str:
    return _package_dir("quadrivio_localization", __file__, 3)


def merge(base: Dict[str, Any], top: Dict[str, Any]) -> Dict[str, Any]:
    out = dict(base)
    for k, v in top.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_params(files: List[str]):
    """LocalizerParams and the node's frames from localization.yaml plus ``files`` in order."""
    import dataclasses

    from .localization_node import NodeParams

    data = load_yaml(os.path.join(package_dir(), "config", "localization.yaml"))
    for path in files:
        extra = load_yaml(path)
        if "localization" in extra and isinstance(extra["localization"], dict) and "name" in extra:
            extra = extra["localization"]  # a scenario file: its localization section
        data = merge(data, extra)
    node_keys = {f.name for f in dataclasses.fields(NodeParams)}
    mine = {k: v for k, v in data.items() if k in node_keys}
    rest = {k: v for k, v in data.items() if k not in node_keys}
    source = " + ".join(["localization.yaml"] + files)
    return from_mapping(LocalizerParams, rest, source), from_mapping(NodeParams, mine, source)


class Ticker:
    """The online node's timer on a bag's clock: before a message received at ``now`` is
    fed, the smoother is updated at every ``1 / rate`` tick up to ``now``. The wall time of
    each update is kept in ``update_s`` (the smoother benchmark reads it)."""

    def __init__(self, loc: Localizer, rate: float, t_start: float) -> None:
        self.loc, self.period = loc, 1.0 / rate
        self.next = math.floor(t_start / self.period + 1.0) * self.period
        self.last_stamp = -math.inf
        self.update_s: List[float] = []

    def until(self, now: float) -> Iterator[Tuple[float, Estimate]]:
        """``(tick time, estimate)`` for every tick up to ``now`` that gave a new estimate."""
        while self.next <= now + 1e-9:
            tick = self.next
            self.next += self.period
            w0 = time.perf_counter()
            est = self.loc.update(tick)
            self.update_s.append(time.perf_counter() - w0)
            if est is not None and est.stamp > self.last_stamp:
                self.last_stamp = est.stamp
                yield tick, est

    def final(self) -> Iterator[Tuple[float, Estimate]]:
        """The tick after the last message."""
        return self.until(self.next)


def parse(argv: List[str]) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="replay", description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bag", help="recorded bag with the sensor topics")
    ap.add_argument("--out", required=True, help="output bag (written atomically)")
    ap.add_argument("--params", action="append", default=[], metavar="YAML",
                    help="parameter file over config/localization.yaml (repeatable), e.g. a calibrate_mag result")
    ap.add_argument("--vehicle", default="", help="vehicle parameters (default: quadrivio_description's)")
    ap.add_argument("--site", default="", help="site (datum, Earth field) (default: quadrivio_description's)")
    ap.add_argument("--gps", default="/gps/fix", help="sensor_msgs/NavSatFix topic")
    ap.add_argument("--imu", default="/imu/data", help="sensor_msgs/Imu topic")
    ap.add_argument("--mag", default="/imu/mag", help="sensor_msgs/MagneticField topic")
    ap.add_argument("--gps-csv", default="", metavar="FILE",
                    help="also write every GPS fix's decision (used, or why not) as CSV; the output bag has them on "
                         "/localization/gps_decisions")
    ap.add_argument("--state", default="/vehicle/state",
                    help="quadrivio_plc/VehicleState topic (or any type with header, wheel_speed, handlebar)")
    ap.add_argument("--map", default="", metavar="YAML",
                    help="import mapping of a recording made with other drivers: its topics, types, fields, units "
                         "(quadrivio_recordings.ros.import_map); replaces --gps/--imu/--mag/--state")
    ap.add_argument("--only-outputs", action="store_true", help="write only the replay's topics")
    ap.add_argument("--quiet", action="store_true", help="no progress lines")
    return ap.parse_args(argv)


def write_decisions_csv(path: str, decisions) -> None:
    """The GPS decisions as CSV (fix time, used, reason, squared Mahalanobis distance), written
    aside and renamed: complete or absent."""
    rows = [f"{t:.6f},{int(bool(used))},{reason},{d2:.6g}\n" for t, used, reason, d2 in decisions]
    atomic_write(path, "t,used,reason,mahalanobis2\n" + "".join(rows), makedirs=True)


SANITY_SAMPLES = 2000  # readings of each kind the unit checks look at (the bag's first)


SPEED_SPAN = 300.0  # [s] of the bag's start in which the wheel speed is compared with the fixes' speed


def check_readings(bag, path: str, topics: Dict[str, str], have, imap, wheel_radius: float = 0.0) -> list:
    """:func:`sanity.check_all` on the bag's first magnetometer and IMU readings, and its
    first ``SPEED_SPAN`` s of wheel speeds and fixes, converted as the replay converts them."""
    import genpy

    wanted = {topics[r]: r for r in ("mag", "imu", "state", "gps") if topics.get(r) and topics[r] in have}
    strengths: list = []
    forces: list = []
    wheel: list = []
    fixes: list = []
    if not wanted:
        return []
    start = None
    offsets: Dict[str, List[float]] = {topic: [] for topic in wanted}  # header stamp less recording time
    for topic, msg, t in read_messages(bag, path, list(wanted), error=ReplayError):
        role = wanted[topic]
        start = t.to_sec() if start is None else start
        late = t.to_sec() - start > SPEED_SPAN
        try:
            if imap is not None:
                msg = imap.convert(role, msg, t)
            if len(offsets[topic]) < SANITY_SAMPLES:
                offsets[topic].append(msg.header.stamp.to_sec() - t.to_sec())
            if role == "mag" and len(strengths) < SANITY_SAMPLES:
                f = msg.magnetic_field
                strengths.append(math.sqrt(f.x ** 2 + f.y ** 2 + f.z ** 2))
            elif role == "imu" and len(forces) < SANITY_SAMPLES:
                a = msg.linear_acceleration
                forces.append(math.sqrt(a.x ** 2 + a.y ** 2 + a.z ** 2))
            elif role == "state" and not late and math.isfinite(msg.wheel_speed):
                wheel.append((msg.header.stamp.to_sec(), float(msg.wheel_speed)))
            elif role == "gps" and not late and msg.status.status >= 0 and math.isfinite(msg.latitude) and \
                    math.isfinite(msg.longitude):
                fixes.append((msg.header.stamp.to_sec(), float(msg.latitude), float(msg.longitude)))
        except ConfigError as exc:
            raise ReplayError(str(exc)) from exc
        except (AttributeError, TypeError, ValueError, genpy.DeserializationError):
            continue  # the replay itself says which messages are unusable
        if len(strengths) >= SANITY_SAMPLES and len(forces) >= SANITY_SAMPLES and late:
            break
    clocks = [("error", w) for w in clock_warnings(offsets)]  # the smoother fuses by stamps
    return clocks + sanity.check_all(strengths, forces, wheel, fixes, wheel_radius)


def run(args: argparse.Namespace) -> Dict[str, Any]:
    import genpy
    import rosbag
    import rospy
    from tf2_msgs.msg import TFMessage

    from . import messages

    params, node = load_params(args.params)
    vehicle = load_vehicle(args.vehicle)
    loc = Localizer(params, vehicle, load_site(args.site))
    bag = open_bag(args.bag, ReplayError)
    topics = {"gps": args.gps, "imu": args.imu, "mag": args.mag, "state": args.state}
    imap = None
    if args.map:
        from quadrivio_recordings.ros import import_map

        imap = import_map.load(args.map)  # a ConfigError names the file and the key
        topics = {r: imap.topics().get(r, "") for r in ROLES}
    feed = {"gps": messages.add_gps, "imu": messages.add_imu, "mag": messages.add_mag, "state": messages.add_state}
    role_of = {t: r for r, t in topics.items()}
    out_dir = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(out_dir, exist_ok=True)
    decisions: list = []  # (fix time, used, reason, d2) of every GPS decision, in order
    counts = {r: 0 for r in ROLES}
    counts.update(bad=0, estimates=0, calibrations=0)
    wall0 = time.perf_counter()
    with atomic_path(args.out) as tmp:  # the bag is whole or absent
        try:
            with bag:
                have = bag.get_type_and_topic_info().topics
                for role in ("gps", "mag"):
                    if topics[role] not in have:
                        raise ReplayError(f"{args.bag} has no {role} topic {topics[role]} (the smoother starts from a fix "
                                          f"and the magnetometer); its topics: {', '.join(sorted(have)) or 'none'}")
                missing = [f"{r} ({topics[r]})" for r in ("imu", "state") if topics[r] not in have]
                if missing and not args.quiet:
                    print(f"[replay] {args.bag} has no {' or '.join(missing)}: localizing without them", file=sys.stderr)
                # the readings' physical sense first: a unit declared wrong is named here, not by a
                # GTSAM traceback ("Indeterminate linear system" for a field read as 0.9 T)
                checks = check_readings(bag, args.bag, topics, have, imap, vehicle.wheel_radius)
                for _level, text in checks:
                    print(f"[replay] WARNING: {text}", file=sys.stderr)
                error = sanity.first_error(checks)
                if error:
                    raise ReplayError(error)
                t_start, t_end = bag.get_start_time(), bag.get_end_time()
                ticker = Ticker(loc, params.rate, t_start)
                last_cal = -math.inf
                next_report = 0.1
                with rosbag.Bag(tmp, "w") as out:

                    def write(estimates, now: float) -> None:
                        nonlocal last_cal
                        for d in loc.pop_gps_decisions():  # when decided (up to the gate's look-ahead after the fix)
                            decisions.append(d)
                            out.write("/localization/gps_decisions", messages.gps_decision(*d), rospy.Time.from_sec(now))
                        for tick, est in estimates:
                            at = rospy.Time.from_sec(tick)
                            out.write("/localization/odom", messages.odometry(est, node.map_frame, node.base_frame), at)
                            counts["estimates"] += 1
                            if tick - last_cal >= node.calibration_period:
                                last_cal = tick
                                out.write("/localization/calibration", messages.calibration(est, loc.calibration_sigma()), at)
                                counts["calibrations"] += 1

                    for topic, raw, t in read_messages(bag, args.bag, raw=True, error=ReplayError):
                        now = t.to_sec()
                        write(ticker.until(now), now)
                        role = role_of.get(topic)
                        if role is not None:
                            try:
                                msg = raw[4]()
                                msg.deserialize(raw[1])
                                if imap is not None:
                                    msg = imap.convert(role, msg, t)
                                feed[role](loc, msg)
                                counts[role] += 1
                            except ConfigError as exc:  # the mapping names a field the messages lack
                                raise ReplayError(str(exc)) from exc
                            except (AttributeError, TypeError, ValueError, genpy.DeserializationError) as exc:
                                counts["bad"] += 1
                                if counts["bad"] <= 5:
                                    print(f"[replay] {topic} at {now:.3f} s: unusable message ({exc}); skipped",
                                          file=sys.stderr)
                        if args.only_outputs or topic.startswith("/localization/"):
                            continue
                        if topic in ("/tf", "/tf_static") and raw[0] == "tf2_msgs/TFMessage":
                            msg = TFMessage()
                            msg.deserialize(raw[1])
                            kept = [tr for tr in msg.transforms
                                    if not (tr.header.frame_id.lstrip("/") == node.map_frame
                                            and tr.child_frame_id.lstrip("/") == node.odom_frame)]
                            if len(kept) != len(msg.transforms):
                                if kept:
                                    out.write(topic, TFMessage(transforms=kept), t)
                                continue
                        out.write(topic, raw, t, raw=True)
                        frac = (now - t_start) / max(t_end - t_start, 1e-9)
                        if not args.quiet and frac >= next_report:
                            print(f"[replay] {100 * frac:3.0f} % of {t_end - t_start:.1f} s, {counts['estimates']} "
                                  f"estimates, {time.perf_counter() - wall0:.1f} s", file=sys.stderr)
                            next_report += 0.1
                    write(ticker.final(), t_end)
        except rosbag.ROSBagException as exc:
            raise ReplayError(f"{args.bag}: corrupt bag ({exc})") from exc
        if counts["estimates"] == 0:
            raise ReplayError(f"{args.bag}: no estimate at all from {counts['gps']} GPS messages and {counts['mag']} "
                              "magnetometer readings (the smoother needs a fix and the magnetometer to start)")
    if args.gps_csv:
        write_decisions_csv(args.gps_csv, decisions)
    c = loc.counters
    counts.update(wall_s=round(time.perf_counter() - wall0, 3), bag_s=round(t_end - t_start, 3),
                  keyframes=c.keyframes, gps_used=c.gps_used, gps_not_used=dict(loc.gate.counts),
                  gps_not_used_summary=loc.gate.summary())
    return counts


def main(argv=None) -> int:
    args = parse(sys.argv[1:] if argv is None else argv)
    try:
        counts = run(args)
    except (ReplayError, ConfigError) as exc:
        print(f"replay: {exc}; nothing written", file=sys.stderr)
        return 2
    print(f"[replay] wrote {args.out}: {counts['estimates']} estimates over {counts['bag_s']} s of bag in "
          f"{counts['wall_s']} s ({counts['bag_s'] / max(counts['wall_s'], 1e-9):.1f}x real time); inputs: "
          f"{counts['gps']} GPS, {counts['imu']} IMU, {counts['mag']} magnetometer, {counts['state']} vehicle state"
          f"{', %d unusable' % counts['bad'] if counts['bad'] else ''}; GPS fixes used {counts['gps_used']}, "
          f"not used: {counts['gps_not_used_summary']}")
    return 0
