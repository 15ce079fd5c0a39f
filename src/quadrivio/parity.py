"""Parity of two runs' bags: the same topics, with the same types, frames, rates and
covariance conventions (the paper's promise that the stack cannot tell the simulator from
the vehicle: ``sim.launch`` against ``real.launch`` on the vehicle's stand-in).

``profile(bag)`` reads, per topic: the message type, the ``header.frame_id`` (and
``child_frame_id``) values, the rate (messages over the span of their receipt times), and
the covariance conventions (per covariance field, its most frequent structure: unknown
(element 0 is -1), or which entries are set and which are zero; a NavSatFix's
``position_covariance_type``). ``compare(a, b)`` lists every
difference, in words; empty when the two agree.
"""

from __future__ import annotations

import math
from collections import Counter, defaultdict
from typing import Dict, Iterable, List, Optional

RATE_TOLERANCE = 0.05  # relative
SKIP = ("/rosout", "/rosout_agg", "/clock", "/diagnostics")  # node names and log lines differ by design
COVARIANCE_FIELDS = ("covariance", "orientation_covariance", "angular_velocity_covariance",
                     "linear_acceleration_covariance", "magnetic_field_covariance", "position_covariance")


def _pattern(values) -> str:
    """The structure of a covariance: "unknown" (element 0 is -1, REP-145's convention), or
    which entries are set (*) and which are zero (0); signs and sizes are data."""
    if len(values) and values[0] == -1.0:
        return "unknown"
    return "".join("0" if v == 0.0 else "*" for v in values)


def _covariances(msg, prefix: str = "", depth: int = 0) -> Iterable:
    """(path, pattern) of every covariance field in ``msg``, nested messages included."""
    if depth > 3 or not hasattr(msg, "__slots__"):
        return
    for name in msg.__slots__:
        value = getattr(msg, name)
        if name in COVARIANCE_FIELDS and isinstance(value, (tuple, list)):
            yield prefix + name, _pattern(value)
        elif hasattr(value, "__slots__") and name != "header":
            yield from _covariances(value, prefix + name + ".", depth + 1)


def profile(bag_path: str, topics: Optional[Iterable[str]] = None, start: float = 5.0) -> Dict[str, Dict]:
    """Per topic: type, frames, children, rate [Hz] over receipt times from ``start`` s after
    the bag's first message, and covariance patterns (the set seen for each field)."""
    import rosbag

    out: Dict[str, Dict] = {}
    times: Dict[str, List[float]] = defaultdict(list)
    with rosbag.Bag(bag_path) as bag:
        info = bag.get_type_and_topic_info().topics
        wanted = [t for t in (topics or info) if t in info and t not in SKIP]
        t0 = bag.get_start_time() + start
        for topic in wanted:
            out[topic] = {"type": info[topic].msg_type, "frames": set(), "children": set(),
                          "covariance": defaultdict(Counter), "messages": 0}
        for topic, msg, t in bag.read_messages(topics=wanted):
            p = out[topic]
            p["messages"] += 1
            if t.to_sec() >= t0:
                times[topic].append(t.to_sec())
            if topic in ("/tf", "/tf_static"):
                for tr in msg.transforms:
                    p["frames"].add(tr.header.frame_id)
                    p["children"].add(tr.child_frame_id)
                continue
            header = getattr(msg, "header", None)
            if header is not None:
                p["frames"].add(header.frame_id)
            if hasattr(msg, "child_frame_id"):
                p["children"].add(msg.child_frame_id)
            if p["messages"] <= 500:  # the convention shows in the first messages
                for field, pat in _covariances(msg):
                    p["covariance"][field][pat] += 1
                if hasattr(msg, "position_covariance_type"):
                    p["covariance"]["position_covariance_type"][str(msg.position_covariance_type)] += 1
    for topic, p in out.items():
        ts = times.get(topic, [])
        p["rate"] = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 2 and ts[-1] > ts[0] else math.nan
        p["covariance"] = {k: v.most_common(1)[0][0] for k, v in p["covariance"].items()}
    return out


def compare(a: Dict[str, Dict], b: Dict[str, Dict], names=("sim.launch", "real.launch"),
            latched=("/tf_static", "/map", "/localization/calibration", "/planner/path")) -> List[str]:
    """Every difference between two profiles, in words (rates only for periodic topics)."""
    problems = []
    for topic in sorted(set(a) | set(b)):
        if topic not in a or topic not in b:
            problems.append(f"{topic}: only in {names[0] if topic in a else names[1]}")
            continue
        pa, pb = a[topic], b[topic]
        if pa["type"] != pb["type"]:
            problems.append(f"{topic}: type {pa['type']} vs {pb['type']}")
        for key in ("frames", "children"):
            if pa[key] != pb[key]:
                problems.append(f"{topic}: {key} {sorted(pa[key])} vs {sorted(pb[key])}")
        if topic not in latched and not (math.isnan(pa["rate"]) and math.isnan(pb["rate"])):
            ra, rb = pa["rate"], pb["rate"]
            if not (math.isfinite(ra) and math.isfinite(rb)) or abs(ra - rb) > RATE_TOLERANCE * max(ra, rb):
                problems.append(f"{topic}: {ra:.2f} Hz vs {rb:.2f} Hz")
        if pa["covariance"] != pb["covariance"]:
            diff = {k: (pa["covariance"].get(k), pb["covariance"].get(k))
                    for k in set(pa["covariance"]) | set(pb["covariance"])
                    if pa["covariance"].get(k) != pb["covariance"].get(k)}
            problems.append(f"{topic}: covariance conventions differ: {diff}")
    return problems
