"""Import mappings: how a recording's topics, message types, fields, units, scales and signs
become Quadrivio's inputs, so that the offline tools read a bag recorded by someone else's
drivers without a hand-written converter.

A mapping is a YAML file with any of five sections (a tool uses the ones it needs)::

    gps:                      # -> sensor_msgs/NavSatFix
      topic: /ublox/fix
      kind: navsatfix         # navsatfix, or position: a point in a local frame (any message type)
      field: pose.position    # position: path to the x, y, z of the point
      frame: enu              # position: enu or ned, about `origin`
      origin: [45.0, 9.0, 120.0]   # position: lat [deg], lon [deg], alt [m] (default: the site's datum)
      std: 2.0                # [m] horizontal std when the message has no covariance (position: always)
      status: FIX             # position: the status to report (FIX, SBAS_FIX, GBAS_FIX)
    imu:                      # -> sensor_msgs/Imu
      topic: /xsens/imu
      accel_field: linear_acceleration
      gyro_field: angular_velocity
      accel_scale: 9.80665    # to m/s^2 (here: readings in g)
      gyro_scale: 0.0174533   # to rad/s (here: deg/s)
      axes: [x, -y, -z]       # our x, y, z as the sensor's signed axes
    mag:                      # -> sensor_msgs/MagneticField
      topic: /xsens/mag
      field: vector           # path to the x, y, z
      unit: gauss             # tesla, gauss, microtesla, nanotesla, or counts (with scale: tesla per count)
      scale: 1.0
      axes: [x, -y, -z]
    state:                    # -> quadrivio_plc/VehicleState (wheel_speed, handlebar)
      topic: /plc/status
      wheel_speed: {field: rear_raw, scale: 0.001, offset: 0.0}    # value = raw x scale + offset [m/s]
      handlebar: {field: steer_raw, scale: -1.0e-4, offset: 0.0}   # [rad]
    setpoint:                 # what was sent to the vehicle (calibrate): speed, handlebar, brake
      topic: /plc/command
      speed: {field: speed_cmd, scale: 0.001}      # [m/s]
      handlebar: {field: steer_cmd, scale: -1.0e-4} # [rad]
      brake: {field: brake_cmd, scale: 0.01}        # [0..1]; leave out when not recorded

Every section also takes ``stamp``: ``header`` (the message's header stamp, default),
``receipt`` (the bag's record time, for messages without a header) or ``auto`` (the
header's where a message has one that is set, else the record time). Messages are read with
the bag's own message definitions (a type need not be installed). :func:`load` checks the
file (unknown keys, units, kinds, axes: one line naming the file and the key);
:meth:`ImportMap.check` checks a bag against it (missing topics, missing fields: one line
naming the topic, the type and the fields it has).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple

from quadrivio_config import ConfigError, load_yaml

ROLES = ("gps", "imu", "mag", "state", "setpoint")
UNITS = {"tesla": 1.0, "gauss": 1e-4, "microtesla": 1e-6, "nanotesla": 1e-9, "counts": None}
STATUS = {"FIX": 0, "SBAS_FIX": 1, "GBAS_FIX": 2}
KEYS = {
    "gps": {"topic", "kind", "field", "frame", "origin", "std", "status", "stamp"},
    "imu": {"topic", "accel_field", "gyro_field", "accel_scale", "gyro_scale", "axes", "stamp"},
    "mag": {"topic", "field", "unit", "scale", "axes", "stamp"},
    "state": {"topic", "wheel_speed", "handlebar", "stamp"},
    "setpoint": {"topic", "speed", "handlebar", "brake", "stamp"},
}
SCALARS = {"state": ("wheel_speed", "handlebar"), "setpoint": ("speed", "handlebar", "brake")}


class ImportError_(ConfigError):
    """A mapping, or a bag against it, that cannot work; the message says which key or field."""


@dataclass
class Scaled:
    field: str
    scale: float = 1.0
    offset: float = 0.0


@dataclass
class Section:
    role: str
    topic: str
    stamp: str = "header"
    opts: Dict[str, Any] = field(default_factory=dict)


def _axes(value, where: str) -> List[Tuple[int, float]]:
    if not isinstance(value, (list, tuple)) or len(value) != 3:
        raise ImportError_(f"{where}: axes must be three of x, y, z with optional '-', e.g. [x, -y, -z]")
    out = []
    for a in value:
        s = str(a).strip()
        sign = -1.0 if s.startswith("-") else 1.0
        name = s.lstrip("+-")
        if name not in ("x", "y", "z"):
            raise ImportError_(f"{where}: axis {a!r} is not x, y or z (with an optional sign)")
        out.append(("xyz".index(name), sign))
    if sorted(i for i, _ in out) != [0, 1, 2]:
        raise ImportError_(f"{where}: axes {list(value)} must use each of x, y, z once")
    return out


def _number(d: Dict, key: str, default: float, where: str) -> float:
    v = d.get(key, default)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise ImportError_(f"{where}.{key} = {v!r} must be a finite number")
    return float(v)


def load(path: str) -> "ImportMap":
    data = load_yaml(path)
    if not isinstance(data, dict) or not data:
        raise ImportError_(f"{path}: an import mapping needs at least one of {', '.join(ROLES)}")
    unknown = sorted(set(data) - set(ROLES))
    if unknown:
        raise ImportError_(f"{path}: unknown section(s) {', '.join(unknown)}; sections: {', '.join(ROLES)}")
    sections = {}
    for role, d in data.items():
        where = f"{path}: {role}"
        if not isinstance(d, dict):
            raise ImportError_(f"{where} must be a mapping of keys")
        bad = sorted(set(d) - KEYS[role])
        if bad:
            raise ImportError_(f"{where}: unknown key(s) {', '.join(bad)}; keys: {', '.join(sorted(KEYS[role]))}")
        topic = d.get("topic")
        if not isinstance(topic, str) or not topic:
            raise ImportError_(f"{where}.topic is missing")
        stamp = d.get("stamp", "header")
        if stamp not in ("header", "receipt", "auto"):
            raise ImportError_(f"{where}.stamp = {stamp!r}: header, receipt or auto")
        s = Section(role, topic if topic.startswith("/") else "/" + topic, stamp)
        if role == "gps":
            kind = d.get("kind", "navsatfix")
            if kind not in ("navsatfix", "position"):
                raise ImportError_(f"{where}.kind = {kind!r}: navsatfix or position")
            s.opts["kind"] = kind
            s.opts["std"] = _number(d, "std", math.nan if kind == "navsatfix" else -1.0, where)
            if kind == "position":
                if s.opts["std"] <= 0:
                    raise ImportError_(f"{where}.std is needed (and > 0) for kind position: such messages "
                                       "carry no covariance")
                s.opts["field"] = str(d.get("field", "pose.position"))
                frame = d.get("frame", "enu")
                if frame not in ("enu", "ned"):
                    raise ImportError_(f"{where}.frame = {frame!r}: enu or ned")
                s.opts["frame"] = frame
                origin = d.get("origin")
                if origin is not None and (not isinstance(origin, (list, tuple)) or len(origin) != 3 or
                                           not all(isinstance(v, (int, float)) for v in origin)):
                    raise ImportError_(f"{where}.origin = {origin!r}: [latitude deg, longitude deg, altitude m]")
                s.opts["origin"] = origin
                status = d.get("status", "FIX")
                if status not in STATUS:
                    raise ImportError_(f"{where}.status = {status!r}: one of {', '.join(STATUS)}")
                s.opts["status"] = STATUS[status]
        elif role == "imu":
            s.opts.update(accel_field=str(d.get("accel_field", "linear_acceleration")),
                          gyro_field=str(d.get("gyro_field", "angular_velocity")),
                          accel_scale=_number(d, "accel_scale", 1.0, where),
                          gyro_scale=_number(d, "gyro_scale", 1.0, where),
                          axes=_axes(d.get("axes", ["x", "y", "z"]), f"{where}.axes"))
        elif role == "mag":
            unit = d.get("unit", "tesla")
            if unit not in UNITS:
                raise ImportError_(f"{where}.unit = {unit!r} is not a unit it knows: {', '.join(UNITS)}")
            scale = _number(d, "scale", 1.0, where)
            if unit == "counts" and "scale" not in d:
                raise ImportError_(f"{where}: unit counts needs scale (tesla per count)")
            s.opts.update(field=str(d.get("field", "magnetic_field")),
                          factor=(UNITS[unit] or 1.0) * scale, axes=_axes(d.get("axes", ["x", "y", "z"]),
                                                                           f"{where}.axes"))
        else:
            for key in SCALARS[role]:
                if key == "brake" and key not in d:
                    continue  # not recorded
                v = d.get(key, {"field": key})
                if isinstance(v, str):
                    v = {"field": v}
                if not isinstance(v, dict) or not isinstance(v.get("field"), str) or set(v) - {"field", "scale",
                                                                                               "offset"}:
                    raise ImportError_(f"{where}.{key} = {v!r}: {{field: NAME, scale: S, offset: O}}")
                s.opts[key] = Scaled(v["field"], _number(v, "scale", 1.0, f"{where}.{key}"),
                                     _number(v, "offset", 0.0, f"{where}.{key}"))
        sections[role] = s
    return ImportMap(path, sections)


def default() -> "ImportMap":
    """Quadrivio's own topics and types (what the stack records)."""
    return ImportMap("(Quadrivio's topics)", {
        "gps": Section("gps", "/gps/fix", opts={"kind": "navsatfix", "std": math.nan}),
        "imu": Section("imu", "/imu/data", opts={"accel_field": "linear_acceleration", "gyro_field": "angular_velocity",
                                                  "accel_scale": 1.0, "gyro_scale": 1.0,
                                                  "axes": [(0, 1.0), (1, 1.0), (2, 1.0)]}),
        "mag": Section("mag", "/imu/mag", opts={"field": "magnetic_field", "factor": 1.0,
                                                 "axes": [(0, 1.0), (1, 1.0), (2, 1.0)]}),
        "state": Section("state", "/vehicle/state", opts={"wheel_speed": Scaled("wheel_speed"),
                                                           "handlebar": Scaled("handlebar")}),
        "setpoint": Section("setpoint", "/vehicle/setpoint/auto", stamp="auto",
                            opts={k: Scaled(k) for k in SCALARS["setpoint"]}),
    })


def get_field(msg, path: str, topic: str, what: str, error=None):
    """The field at dotted ``path`` of ``msg``; ``error`` (default :class:`ImportError_`)
    names the topic, the type, the field and the fields there when it is missing."""
    obj = msg
    for part in path.split("."):
        if not hasattr(obj, part):
            slots = getattr(obj, "__slots__", [])
            raise (error or ImportError_)(
                f"{topic} ({getattr(msg, '_type', type(msg).__name__)}) has no field '{path}' for {what} "
                f"(at '{part}'; fields there: {', '.join(slots) or 'none'})")
        obj = getattr(obj, part)
    return obj


_get = get_field


def _vec(obj, axes: Sequence[Tuple[int, float]], scale: float) -> Tuple[float, float, float]:
    raw = (float(obj.x), float(obj.y), float(obj.z))
    return tuple(sign * raw[i] * scale for i, sign in axes)  # type: ignore[return-value]


class ImportMap:
    def __init__(self, path: str, sections: Dict[str, Section]) -> None:
        self.path, self.sections = path, sections

    def topics(self) -> Dict[str, str]:
        return {role: s.topic for role, s in self.sections.items()}

    def role_of(self, topic: str) -> Optional[str]:
        for role, s in self.sections.items():
            if s.topic == topic:
                return role
        return None

    def check(self, bag, bag_path: str, needed: Sequence[str]) -> List[str]:
        """Raise naming what ``needed`` roles lack in the bag; return the other roles the bag lacks."""
        have = bag.get_type_and_topic_info().topics
        missing = []
        for role in ROLES:
            if role not in self.sections:
                if role in needed:
                    raise ImportError_(f"{self.path}: no '{role}' section, and the tool needs it")
                continue
            topic = self.sections[role].topic
            if topic not in have:
                if role in needed:
                    raise ImportError_(f"{bag_path} has no {role} topic {topic} ({self.path}); its topics: "
                                       f"{', '.join(sorted(have)) or 'none'}")
                missing.append(f"{role} ({topic})")
        return missing

    def _stamp(self, s: Section, msg, t_recv):
        import rospy

        if s.stamp == "receipt":
            return t_recv
        if s.stamp == "auto":
            st = getattr(getattr(msg, "header", None), "stamp", None)
            return rospy.Time(st.secs, st.nsecs) if st is not None and (st.secs or st.nsecs) else t_recv
        st = _get(msg, "header.stamp", s.topic, f"{s.role} stamps (set stamp: receipt or auto for messages without one)")
        return rospy.Time(st.secs, st.nsecs)

    def stamp(self, role: str, msg, t_recv) -> float:
        """A message's time [s] as the ``role`` section says (``t_recv``: the record time)."""
        return self._stamp(self.sections[role], msg, t_recv).to_sec()

    def scalars(self, role: str, msg) -> Dict[str, float]:
        """The scaled numbers of a ``state`` or ``setpoint`` message, by our names."""
        s = self.sections[role]
        out = {}
        for key in SCALARS[role]:
            sc: Optional[Scaled] = s.opts.get(key)
            if sc is not None:
                out[key] = float(_get(msg, sc.field, s.topic, key)) * sc.scale + sc.offset
        return out

    def convert(self, role: str, msg, t_recv):
        """``msg`` (of the bag's own type) as our message of ``role``; ``t_recv`` the record time."""
        s = self.sections[role]
        o = s.opts
        stamp = self._stamp(s, msg, t_recv)
        if role == "gps":
            from sensor_msgs.msg import NavSatFix, NavSatStatus

            if o["kind"] == "navsatfix":
                out = NavSatFix()
                for k in ("latitude", "longitude", "altitude", "position_covariance", "position_covariance_type"):
                    setattr(out, k, _get(msg, k, s.topic, "the fix"))
                out.status.status = int(_get(msg, "status.status", s.topic, "the fix"))
                if out.position_covariance_type == NavSatFix.COVARIANCE_TYPE_UNKNOWN and math.isfinite(o["std"]):
                    v = o["std"] ** 2
                    out.position_covariance = [v, 0, 0, 0, v, 0, 0, 0, 4 * v]
                    out.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
            else:
                p = _get(msg, o["field"], s.topic, "the position")
                e, n, u = float(p.x), float(p.y), float(p.z)
                if o["frame"] == "ned":
                    e, n, u = n, e, -u
                out = NavSatFix()
                out.latitude, out.longitude, out.altitude = self._frame(o).enu_to_lla(e, n, u)
                v = o["std"] ** 2
                out.position_covariance = [v, 0, 0, 0, v, 0, 0, 0, 4 * v]
                out.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
                out.status.status = o["status"]
            out.status.service = NavSatStatus.SERVICE_GPS
        elif role == "imu":
            from sensor_msgs.msg import Imu

            out = Imu()
            a = _vec(_get(msg, o["accel_field"], s.topic, "the acceleration"), o["axes"], o["accel_scale"])
            w = _vec(_get(msg, o["gyro_field"], s.topic, "the angular rate"), o["axes"], o["gyro_scale"])
            out.linear_acceleration.x, out.linear_acceleration.y, out.linear_acceleration.z = a
            out.angular_velocity.x, out.angular_velocity.y, out.angular_velocity.z = w
            out.orientation_covariance[0] = -1.0
        elif role == "mag":
            from sensor_msgs.msg import MagneticField

            out = MagneticField()
            m = _vec(_get(msg, o["field"], s.topic, "the field"), o["axes"], o["factor"])
            out.magnetic_field.x, out.magnetic_field.y, out.magnetic_field.z = m
        elif role == "state":
            from quadrivio_plc.msg import VehicleState

            out = VehicleState()
            for key, value in self.scalars(role, msg).items():
                setattr(out, key, value)
        else:
            raise ImportError_(f"{self.path}: the {role} section is read by calibrate only, not converted")
        out.header.stamp = stamp
        return out

    def _frame(self, o):
        if "_frame" not in o:
            from quadrivio_description.site import Datum, SiteParams, load_site

            site = load_site()
            if o.get("origin") is not None:
                lat, lon, alt = o["origin"]
                site = SiteParams(Datum(float(lat), float(lon), float(alt)), site.magnetic_field, site.utc_epoch)
            o["_frame"] = site.local_frame()
        return o["_frame"]
