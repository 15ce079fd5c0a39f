"""Reading a run's bag into :class:`quadrivio.metrics.RunData` (the bag's own message
definitions are enough: no generated classes are needed)."""

from __future__ import annotations

import contextlib
import math
from collections import Counter, defaultdict
from typing import Callable, Dict, Iterable, List, Optional

import numpy as np

from quadrivio_description.frames import yaw_from_quaternion
from quadrivio_recordings.clocks import clock_warnings
from quadrivio_recordings.ros.bag import open_bag, read_messages
from quadrivio_description.site import SiteParams
from quadrivio_description.vehicle import VehicleParams

from quadrivio_navigation.costmap import Footprint

from ..metrics import RunData, Series
from ..parity import SKIP, covariances

TOPICS = {
    "ground_truth": "/ground_truth/odom",
    "estimate": "/localization/odom",
    "predicted": "/localization/predicted",
    "gps": "/gps/fix",
    "path": "/planner/path",
    "status": "/follower/status",
    "setpoint": "/vehicle/setpoint/auto",
    "vehicle": "/vehicle/state",
    "calibration": "/localization/calibration",
    "planner": "/planner/status",
    "goal": "/move_base_simple/goal",
    "map": "/map",
    "guard": "/guard/status",
    "actors": "/ground_truth/actors",
    "map_bodies": "/ground_truth/map_bodies",
    "contacts": "/ground_truth/contacts",
    "local": "/local_obstacles",
    "gps_decisions": "/localization/gps_decisions",
}
# Not /clock: a bag's messages carry their time, `rosbag play --clock` publishes it, and a
# recorded /clock would make a second publisher of it (12 % of a run's messages).
RECORD = sorted(set(TOPICS.values()) | {"/imu/data", "/imu/mag", "/gps/vel", "/safety/rollover", "/tf", "/tf_static",
                                        "/diagnostics", "/rosout_agg", "/joint_states", "/scan/front", "/scan/rear",
                                        "/vehicle/setpoint/request", "/local_obstacles"})
CALIBRATION_FIELDS = ("wheel_speed_scale", "handlebar_offset", "steering_gain", "gyro_bias")


class BagError(ValueError):
    pass


def _yaw(q) -> float:
    return yaw_from_quaternion(q.x, q.y, q.z, q.w)


def _body(a) -> tuple:
    """A quadrivio_sim/Actor as RunData's actors and map_bodies hold it."""
    return (a.name, a.kind, a.shape, a.pose.x, a.pose.y, a.pose.theta, a.length, a.width)


_series = Series.from_rows


# What is null in metrics.json without each topic (analyze names the missing ones)
NEEDED_FOR = {
    "ground_truth": "every error against the truth (localization, prediction, GPS, cross-track)",
    "estimate": "the localization's errors and plots",
    "gps": "the GPS's error and fix fraction",
    "vehicle": "the control plot's measured speed and handlebar",
    "status": "completed and the follower's progress",
    "calibration": "the calibration plot",
    "guard": "the guard's stops, guard.png and a picture of each stop",
}


def topics_for(imap=None) -> Dict[str, str]:
    """The topic of each kind: ours, or for gps and vehicle those of an import mapping."""
    topics = dict(TOPICS)
    if imap is not None:
        for kind, role in (("gps", "gps"), ("vehicle", "state")):
            if role in imap.sections:
                topics[kind] = imap.sections[role].topic
    return topics


def missing_topics(path: str, imap=None, bag=None) -> List[str]:
    """The kinds of NEEDED_FOR whose topic the bag lacks, as 'topic (what is null)'.
    ``bag``: the bag at ``path`` already open (left open)."""
    topics = topics_for(imap)
    with _opened(path, bag) as b:
        have = b.get_type_and_topic_info().topics
    return [f"{topics[k]} ({why})" for k, why in NEEDED_FOR.items() if topics[k] not in have]


def _opened(path: str, bag=None):
    """A context of the bag at ``path``: ``bag`` as it is (its owner closes it), or the file
    opened here and closed on leaving. Opening reads the bag's whole index: a second of an
    hour's recording, each time."""
    return contextlib.nullcontext(bag) if bag is not None else open_bag(path, BagError)


CLOCK_SAMPLES = 500  # messages of each topic whose stamps are compared with their recording times


def read_run(path: str, site: SiteParams, vehicle: VehicleParams, imap=None, bag=None,
             progress: Optional[Callable[[float], None]] = None) -> RunData:
    """``imap``: an import mapping whose gps and state sections replace /gps/fix and /vehicle/state;
    ``bag``: the bag at ``path`` already open (left open); ``progress(t)``: called with the
    recording time reached, after each hundredth of the bag's span
    (:class:`quadrivio_recordings.progress.BagProgress`)."""
    import rosbag

    topics = topics_for(imap)
    role_of = {"gps": "gps", "vehicle": "state"}
    frame = site.local_frame()
    rows: Dict[str, List[tuple]] = {k: [] for k in TOPICS}
    path_xy = None
    path_poses = None
    goal = None
    grid = None
    actors: List[tuple] = []
    map_bodies = None
    paths: List[tuple] = []  # (stamp, xy) of every path: a replan replaces the route from then on
    local_marks: set = set()  # every cell the local obstacle layer marked during the run (map frame, 0.1 m)
    contacts = None
    decisions: List[tuple] = []  # (fix stamp, used, reason, d2) of localization/gps_decisions
    by_topic = {v: k for k, v in topics.items()}
    offsets: Dict[str, List[float]] = defaultdict(list)  # topic -> header stamp less recording time, the first ones
    with _opened(path, bag) as bag:
        step = next_report = math.inf
        if progress is not None and bag.get_message_count():
            t_begin = bag.get_start_time()
            step = (bag.get_end_time() - t_begin) / 100.0 or math.inf
            next_report = t_begin + step
        try:
            for topic, m, t_recv in read_messages(bag, path, list(topics.values()), error=BagError):
                if t_recv.to_sec() >= next_report:
                    progress(t_recv.to_sec())
                    next_report += step
                kind = by_topic[topic]
                if imap is not None and kind in role_of and role_of[kind] in imap.sections:
                    m = imap.convert(role_of[kind], m, t_recv)  # a ConfigError names a missing field
                if kind == "path":
                    path_poses = np.array([(p.pose.position.x, p.pose.position.y, _yaw(p.pose.orientation))
                                           for p in m.poses]) if m.poses else None
                    path_xy = path_poses[:, :2] if path_poses is not None else None
                    if path_xy is not None:
                        paths.append((m.header.stamp.to_sec(), path_xy))
                    continue
                if kind == "goal":
                    goal = (m.pose.position.x, m.pose.position.y, _yaw(m.pose.orientation))
                    continue
                if kind == "map":
                    grid = _grid(m)
                    continue
                if kind == "map_bodies":
                    map_bodies = [_body(a) for a in m.actors]
                    continue
                if kind == "actors":
                    actors.append((m.header.stamp.to_sec(), [_body(a) for a in m.actors]))
                    continue
                if kind == "local":
                    g = _grid(m)
                    if g is not None:
                        rows_, cols_ = np.nonzero(g.data >= 100)
                        if len(rows_):
                            x, y, _ = g.to_map_frame((cols_ + 0.5) * g.resolution, (rows_ + 0.5) * g.resolution)
                            local_marks.update(zip(np.round(np.asarray(x, float), 1), np.round(np.asarray(y, float), 1)))
                    continue
                if kind == "gps_decisions":
                    decisions.append((m.header.stamp.to_sec(), bool(m.used), m.reason, m.mahalanobis2))
                    continue
                if kind == "contacts":
                    contacts = (contacts or []) + [(m.header.stamp.to_sec(), m.body, m.kind, m.speed)]
                    continue
                t = m.header.stamp.to_sec()
                if len(offsets[topic]) < CLOCK_SAMPLES:
                    offsets[topic].append(t - t_recv.to_sec())
                if kind in ("ground_truth", "estimate", "predicted"):
                    p = m.pose.pose
                    rows[kind].append((t, p.position.x, p.position.y, _yaw(p.orientation), m.twist.twist.linear.x,
                                       m.twist.twist.angular.z))
                elif kind == "gps":
                    if m.status.status >= 0 and all(map(math.isfinite, (m.latitude, m.longitude, m.altitude))):
                        e, n, _ = frame.lla_to_enu(m.latitude, m.longitude, m.altitude)
                    else:
                        e = n = math.nan
                    rows[kind].append((t, e, n, m.status.status))
                elif kind == "status":
                    rows[kind].append((t, m.status, m.progress, m.cross_track))
                elif kind == "setpoint":
                    rows[kind].append((t, m.speed, m.handlebar, m.brake))
                elif kind == "guard":
                    rows[kind].append((t, m.action, m.speed_limit, m.free_distance, m.protective_distance,
                                       m.scan_stamp.to_sec(), m.direction, m.requested_speed,
                                       1.0 if m.field == "zone" else 0.0, m.measured_speed,
                                       getattr(m, "requested_handlebar", math.nan),
                                       getattr(m, "measured_handlebar", math.nan)))
                elif kind == "vehicle":
                    rows[kind].append((t, m.wheel_speed, m.handlebar))
                elif kind == "planner":
                    rows[kind].append((t, m.state, m.planning_time, m.length))
                    if m.state == 2:  # FOUND: the goal it planned for
                        g = m.goal.pose
                        goal = (g.position.x, g.position.y, _yaw(g.orientation))
                elif kind == "calibration":
                    rows[kind].append((t, *(getattr(m, f) for f in CALIBRATION_FIELDS), m.mag_hard_iron[0] * 1e6,
                                       m.mag_hard_iron[1] * 1e6, *m.sigma[:4], m.sigma[4] * 1e6, m.sigma[5] * 1e6))
        except rosbag.ROSBagException as exc:
            raise BagError(f"{path}: corrupt bag ({exc})") from exc
    pose_cols = ("x", "y", "yaw", "vx", "wz")
    cal_cols = CALIBRATION_FIELDS + ("mag_hard_iron_x", "mag_hard_iron_y") + tuple(
        f + "_sigma" for f in CALIBRATION_FIELDS + ("mag_hard_iron_x", "mag_hard_iron_y"))
    return RunData(
        ground_truth=_series(rows["ground_truth"], pose_cols),
        estimate=_series(rows["estimate"], pose_cols),
        predicted=_series(rows["predicted"], pose_cols),
        gps=_series(rows["gps"], ("e", "n", "status")),
        gps_decisions=decisions,
        path=path_xy,
        status=_series(rows["status"], ("status", "progress", "cross_track")),
        lever=tuple(vehicle.sensors["gps_link"].xyz[:2]),
        setpoint=_series(rows["setpoint"], ("speed", "handlebar", "brake")),
        vehicle=_series(rows["vehicle"], ("speed", "handlebar")),
        calibration=_series(rows["calibration"], cal_cols),
        warnings=clock_warnings(offsets),
        goal=goal,
        map=grid,
        planner=_series(rows["planner"], ("state", "planning_time", "length")),
        path_poses=path_poses,
        footprint=Footprint.from_vehicle(vehicle) if grid is not None else None,
        guard=_series(rows["guard"], ("action", "limit", "free", "protective", "scan_stamp", "direction",
                                      "requested", "zone", "measured", "handlebar_requested",
                                      "handlebar_measured")),
        actors=sorted(actors, key=lambda a: a[0]),
        map_bodies=map_bodies,
        paths=paths,
        local_marks=np.array(sorted(local_marks)) if local_marks else np.zeros((0, 2)),
        # the simulator reports contacts as they begin: none recorded in a simulated run with
        # bodies to touch (actors, obstacles, a map) is none made
        contacts=contacts if contacts is not None else (
            [] if rows["ground_truth"] and (actors or grid is not None or map_bodies) else None),
    )


def _grid(m):
    """A nav_msgs/OccupancyGrid as quadrivio_navigation's OccupancyGrid (None if malformed)."""
    from quadrivio_navigation.maps import OccupancyGrid

    info = m.info
    if info.width * info.height == 0 or len(m.data) != info.width * info.height:
        return None
    data = np.asarray(m.data, dtype=np.int8).reshape(info.height, info.width)
    o = info.origin
    return OccupancyGrid(data.copy(), float(info.resolution), (o.position.x, o.position.y, _yaw(o.orientation)))


def topic_profile(bag_path: str, topics: Optional[Iterable[str]] = None, start: float = 5.0) -> Dict[str, Dict]:
    """A run's topics for :func:`quadrivio.parity.compare`. Per topic: type, frames, children, rate [Hz] over receipt times from ``start`` s after
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
                for field, pat in covariances(msg):
                    p["covariance"][field][pat] += 1
                if hasattr(msg, "position_covariance_type"):
                    p["covariance"]["position_covariance_type"][str(msg.position_covariance_type)] += 1
    for topic, p in out.items():
        ts = times.get(topic, [])
        p["rate"] = (len(ts) - 1) / (ts[-1] - ts[0]) if len(ts) > 2 and ts[-1] > ts[0] else math.nan
        p["covariance"] = {k: v.most_common(1)[0][0] for k, v in p["covariance"].items()}
    return out


def _static_unstamped(raw) -> bytes:
    """A /tf_static message serialised again with its transforms' stamps (and seqs) zeroed."""
    import io

    import rospy

    msg = raw[4]()
    msg.deserialize(raw[1])
    for t in msg.transforms:
        t.header.stamp, t.header.seq = rospy.Time(0), 0
    buf = io.BytesIO()
    msg.serialize(buf)
    return buf.getvalue()


def _wall_clock_zeroed(raw, fields) -> bytes:
    """A message serialised again with its ``fields`` (wall-clock figures) and header.seq zeroed."""
    import io

    msg = raw[4]()
    msg.deserialize(raw[1])
    for name in fields:
        setattr(msg, name, type(getattr(msg, name))(0))
    msg.header.seq = 0
    buf = io.BytesIO()
    msg.serialize(buf)
    return buf.getvalue()


def streams(bag_path: str, skip: Iterable[str] = ()) -> Dict[tuple, List[bytes]]:
    """Per (topic, publisher) the serialised messages of a bag, in order, ``header.seq``
    zeroed, and the stamps of /tf_static's transforms and the wall-clock fields of
    :data:`quadrivio.determinism.WALL_CLOCK_FIELDS` (:func:`quadrivio.determinism.compare`);
    topics in ``skip`` left out."""
    from ..determinism import WALL_CLOCK_FIELDS

    import rosbag

    skip = set(skip)
    out: Dict[tuple, List[bytes]] = defaultdict(list)
    try:
        bag = rosbag.Bag(bag_path)
    except (OSError, rosbag.ROSBagException) as exc:
        raise BagError(f"{bag_path}: cannot read the bag: {exc}") from exc
    with bag:
        for topic, raw, _t, header in bag.read_messages(raw=True, return_connection_header=True):
            if topic in skip:
                continue
            caller = header.get("callerid", b"?")
            data = raw[1]
            if topic == "/tf_static":
                # a static transform holds at every time (tf2 ignores its stamp); its publisher
                # stamps it with the clock when it gets round to it: robot_state_publisher's
                # one-shot timer reads the first /clock it sees, 0.02 or 0.03 s, which lockstep
                # does not sequence (it is no member)
                data = _static_unstamped(raw)
            elif raw[0] in WALL_CLOCK_FIELDS:
                data = _wall_clock_zeroed(raw, WALL_CLOCK_FIELDS[raw[0]])
            elif getattr(raw[4], "_has_header", False) and len(data) >= 4:
                # header.seq is the transport's: rospy numbers a latched message once per
                # subscriber it reaches, so it tells who connected first, not what the node did
                data = b"\0\0\0\0" + bytes(data[4:])
            out[(topic, caller.decode() if isinstance(caller, bytes) else str(caller))].append(data)
    return out
