"""Parity of two runs' bags: the same topics, with the same types, frames, rates and
covariance conventions (the paper's promise that the stack cannot tell the simulator from
the vehicle: ``sim.launch`` against ``real.launch`` on the vehicle's stand-in).

``quadrivio.ros.bag.topic_profile(bag)`` reads, per topic: the message type, the ``header.frame_id`` (and
``child_frame_id``) values, the rate (messages over the span of their receipt times), and
the covariance conventions (per covariance field, its most frequent structure: unknown
(element 0 is -1), or which entries are set and which are zero; a NavSatFix's
``position_covariance_type``). ``compare(a, b)`` lists every
difference, in words; empty when the two agree.
"""

from __future__ import annotations

import math
from typing import Dict, Iterable, List

RATE_TOLERANCE = 0.05  # relative
SKIP = ("/rosout", "/rosout_agg", "/clock", "/diagnostics")  # node names and log lines differ by design
COVARIANCE_FIELDS = ("covariance", "orientation_covariance", "angular_velocity_covariance",
                     "linear_acceleration_covariance", "magnetic_field_covariance", "position_covariance")


def pattern(values) -> str:
    """The structure of a covariance: "unknown" (element 0 is -1, REP-145's convention), or
    which entries are set (*) and which are zero (0); signs and sizes are data."""
    if len(values) and values[0] == -1.0:
        return "unknown"
    return "".join("0" if v == 0.0 else "*" for v in values)


def covariances(msg, prefix: str = "", depth: int = 0) -> Iterable:
    """(path, pattern) of every covariance field in ``msg``, nested messages included."""
    if depth > 3 or not hasattr(msg, "__slots__"):
        return
    for name in msg.__slots__:
        value = getattr(msg, name)
        if name in COVARIANCE_FIELDS and isinstance(value, (tuple, list)):
            yield prefix + name, pattern(value)
        elif hasattr(value, "__slots__") and name != "header":
            yield from covariances(value, prefix + name + ".", depth + 1)


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
