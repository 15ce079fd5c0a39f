"""The guard's stops in a bag, with the scans it judged: :class:`quadrivio.stop_views.StopScene`.

A stop is a ``/guard/status`` whose action turns to STOP or FAULT. Its scans are those of
every scanner the guard reads, recorded from half a second before the stop to just after it:
for the scanner the status names, the scan of its ``scan_stamp``; for the others, their
newest up to the stop. A laser's mount comes from the bag's ``/tf_static`` (then ``/tf``),
chained to ``base_link`` (a laser on a bracket on a mast, upside down, ...), and only when
the bag has none from the vehicle description's ``sensors``, which the picture then says.
"""

from __future__ import annotations

import math
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from quadrivio_description.frames import matrix_from_quaternion, rpy_matrix
from quadrivio_recordings.ros.bag import read_messages

from ..stop_views import MAX_VIEWS, StopScene, add_world, stopped_something
from .bag import BagError

GUARD_TOPIC = "/guard/status"
WINDOW = 0.5  # [s] of scans read before a stop
TF_SCAN = 10.0  # [s] of /tf searched for the lasers' mounts when /tf_static lacks them
MAP_RADIUS = 20.0  # [m] map cells drawn about the pose


def chain_to(frame: str, edges: Dict[str, Tuple[str, np.ndarray, np.ndarray]], base: str
             ) -> Optional[Tuple[np.ndarray, np.ndarray]]:
    """(R, p) of ``frame`` in ``base`` from child -> (parent, R, p) edges; None when the
    chain does not reach ``base`` (or loops)."""
    R, p = np.eye(3), np.zeros(3)
    seen = set()
    while frame != base:
        if frame in seen or frame not in edges:
            return None
        seen.add(frame)
        parent, Rp, pp = edges[frame]
        R, p = Rp @ R, Rp @ p + pp
        frame = parent
    return R, p


def laser_mounts(bag, path: str, frames: Sequence[str], vehicle, base: str = "base_link"
                 ) -> Tuple[Dict[str, Tuple[np.ndarray, np.ndarray]], str]:
    """Each frame's (R, p) in ``base`` and where they came from."""
    import rospy

    edges: Dict[str, Tuple[str, np.ndarray, np.ndarray]] = {}
    have = bag.get_type_and_topic_info().topics
    t0 = bag.get_start_time() if bag.get_message_count() else 0.0
    for topic in ("/tf_static", "/tf"):
        if topic not in have or all(chain_to(f, edges, base) is not None for f in frames):
            continue
        # /tf: its first TF_SCAN seconds (a mount published as a dynamic transform repeats)
        end = None if topic == "/tf_static" else rospy.Time.from_sec(t0 + TF_SCAN)
        for _, m, _ in read_messages_between(bag, path, topic, end):
            for tr in m.transforms:
                child = tr.child_frame_id.lstrip("/")
                if child not in edges:
                    t, q = tr.transform.translation, tr.transform.rotation
                    R = np.array(matrix_from_quaternion(q.x, q.y, q.z, q.w))
                    edges[child] = (tr.header.frame_id.lstrip("/"), R, np.array([t.x, t.y, t.z]))
            if all(chain_to(f, edges, base) is not None for f in frames):
                break
    mounts, described = {}, []
    for f in frames:
        found = chain_to(f, edges, base)
        if found is None and f in vehicle.sensors:
            s = vehicle.sensors[f]
            found = (np.array(rpy_matrix(s.rpy)), np.array(s.xyz, float))
            described.append(f)
        if found is not None:
            mounts[f] = found
    source = "the bag's TF" if not described else (
        "the vehicle description" if len(described) == len(mounts) else
        f"the bag's TF, {', '.join(described)} from the vehicle description")
    return mounts, source


def read_messages_between(bag, path: str, topic: str, end=None):
    """``read_messages`` of one topic up to the bag time ``end`` (None: all of it)."""
    for item in read_messages(bag, path, [topic], error=BagError):
        if end is not None and item[2] > end:
            return
        yield item


def _stop_statuses(bag, path: str, limit: int) -> Tuple[List[object], int]:
    out, prev, count = [], None, 0
    for _, m, _ in read_messages(bag, path, [GUARD_TOPIC], error=BagError):
        if stopped_something(m.action, getattr(m, "measured_speed", math.inf)) and m.action != prev:
            count += 1
            if len(out) < limit:
                out.append(m)
        prev = m.action
    return out, count


def read_stop_scenes(bag, path: str, run, vehicle, scanners: Sequence[Tuple[str, ...]],
                     limit: int = MAX_VIEWS) -> Tuple[List[StopScene], int]:
    """The first ``limit`` stops of the bag as scenes, and how many stops it holds.
    ``scanners``: (topic, laser frame[, no_return]) of each laser the guard reads (no_return:
    how its driver reports no echo, ``inf`` by default: fields.rep117_ranges)."""
    import rospy

    from quadrivio_navigation.fields import rep117_ranges, scan_points

    have = bag.get_type_and_topic_info().topics
    if GUARD_TOPIC not in have:
        return [], 0
    statuses, count = _stop_statuses(bag, path, limit)
    if not statuses:
        return [], count
    topics = {("/" + s[0].lstrip("/")): s[1] for s in scanners}
    no_return = {("/" + s[0].lstrip("/")): (s[2] if len(s) > 2 else "inf") for s in scanners}
    present = [t for t in topics if t in have]
    named: Dict[str, str] = {}  # the frame each recorded laser's scans name (else the configured one)
    if present:
        for topic, m, _ in read_messages(bag, path, present, error=BagError):
            named.setdefault(topic, m.header.frame_id.lstrip("/") or topics[topic])
            if len(named) == len(present):
                break
    frames = sorted(set(named.values()))
    mounts, source = laser_mounts(bag, path, frames, vehicle)
    scenes = []
    for st in statuses:
        t = st.header.stamp.to_sec()
        scanner = getattr(st, "scanner", "")
        judged = "/" + scanner.lstrip("/") if scanner else ""
        want = st.scan_stamp.to_sec() if hasattr(st, "scan_stamp") else 0.0
        best: Dict[str, object] = {}
        if present:
            start, end = rospy.Time.from_sec(max(0.0, t - WINDOW)), rospy.Time.from_sec(t + 0.05)
            for topic, m, _ in bag.read_messages(topics=present, start_time=start, end_time=end):
                stamp = m.header.stamp.to_sec()
                if topic == judged and want > 0.0:
                    if abs(stamp - want) < 1e-6:
                        best[topic] = m
                elif stamp <= t + 1e-9:
                    best[topic] = m  # the newest up to the stop (messages come in time order)
        scans, ages = {}, {}
        for topic, m in best.items():
            frame = m.header.frame_id.lstrip("/") or topics[topic]
            mount = mounts.get(frame)
            if mount is None:
                continue
            R, p = mount
            ranges = rep117_ranges(m.ranges, m.range_max, no_return[topic])  # the driver's "nothing seen": +inf
            pts = scan_points(ranges, m.angle_min, m.angle_increment, m.range_min, m.range_max,
                              (float(p[0]), float(p[1]), 0.0), rotation=R)
            scans[topic.lstrip("/")] = pts.xy
            ages[topic.lstrip("/")] = t - m.header.stamp.to_sec()
        nearest = (st.nearest.x, st.nearest.y) if getattr(st, "has_nearest", False) else None

        def f(name: str, default: float = math.nan) -> float:  # a field an older GuardStatus may lack
            return float(getattr(st, name, default))

        scenes.append(add_world(StopScene(t, int(st.action), getattr(st, "field", ""), getattr(st, "reason", ""),
                                          scanner, int(getattr(st, "direction", 0)), f("requested_speed"),
                                          f("measured_speed"), f("requested_handlebar"), f("measured_handlebar"),
                                          f("protective_distance", 0.0), f("warning_distance", 0.0),
                                          f("free_distance", math.inf), nearest, scans, ages, source), run,
                                MAP_RADIUS))
    return scenes, count
