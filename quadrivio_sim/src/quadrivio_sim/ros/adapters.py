"""Layer-2 sensor adapters: simulator readings -> exactly what the real drivers publish.

Each adapter is its own node (paper section 3.3: "a ROS node that reads the messages
published by the simulator and converts them into a format which matches the one
produced by sensors on the real vehicle"). It reads ``/sim/...``, adds the
imperfections of :mod:`quadrivio_sim.noise` with its own seeded generator, stamps
the message with the measurement time and delivers it after the sensor's latency.

Common parameters (private, see ``config/<sensor>.yaml``): ``~frame_id``,
``~latency/delay``, ``~latency/jitter`` [s], the sensor's noise block, and the run's seed
(``/run/seed`` or ``/scenario/seed``); a scenario's ``/scenario/sensors/<sensor>``
overrides any of them. Delivery happens on a sim-time timer of period
``~release_period`` (default 1 ms: every /clock tick). Readings with non-finite values
(laser ranges excepted: inf and NaN are valid there, REP-117) or stamps ahead of the
clock are dropped and counted; when the clock moves back (the simulator's ``~reset``)
the readings waiting for their delivery time are dropped (not held until sim time
passes their pre-reset stamps), and the noise and latency models start again from the
run's seed, as at launch.

Adapters: ``gps`` (sim/gps -> gps/fix NavSatFix, gps/vel TwistStamped, optional NMEA on
a pseudo-terminal or TCP), ``imu`` (sim/imu -> imu/data Imu), ``mag`` (sim/mag ->
imu/mag MagneticField), ``laser`` (scan_in -> scan LaserScan), ``camera`` (image_in,
camera_info_in -> image_raw, camera_info). All topic names are relative, remapped in launch.

Publishing. Each output is written to its subscribers in the delivering thread while they
keep up (``quadrivio_runtime.ros.direct``), with the queue sizes a real driver's
publisher has only for a subscriber that falls behind; readings are delivered by the
thread that receives /clock (no thread wake-up per tick).

Processes. ``sensor_adapters`` hosts several adapters in one process, still outside the
simulator (the paper's layer 2), which is how ``adapters.launch`` runs them: every Python
process pays for each /clock tick, its timer threads and its connections, whatever it
publishes (about 0.014 CPU s per simulated second each, measured), and five adapters in
one process pay it once. Its inputs are read by one thread
(``quadrivio_runtime.ros.receiver``): they all arrive with the simulator's step, and
with a rospy thread per input the threads woken together fought for the GIL (a sixth
less CPU for the process). Its parameters, after costmap_2d's plugins::

    adapters: [{name: imu_adapter, type: imu}, {name: laser_front, type: laser}, ...]
    imu_adapter: {...the adapter's parameters, config/imu.yaml...}

and each hosted adapter's topics are its standalone names under its own name
(``imu_adapter/imu/data``, ``laser_front/scan_in``), remapped in launch. An adapter's
noise stream and its diagnostics are named after it, not after the process: the same seed
gives the same readings hosted or alone. ``gps_adapter``, ``imu_adapter``, ``mag_adapter``,
``laser_adapter`` and ``camera_adapter`` run one adapter as its own node, with its
parameters private and its topics in the node's namespace.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from typing import Any, Callable, Deque, Dict, List, Tuple

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import CameraInfo, Image, Imu, LaserScan, MagneticField, NavSatFix, NavSatStatus

from quadrivio_runtime.ros import diagnostics, init_node
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import fatal, node_params, private_params, run_seed, site_params, with_scenario
from quadrivio_runtime.ros.timer import check_clock, guarded_timer, input_guard, on_clock_jump, publish
from quadrivio_sim.msg import RawGps

from ..adapter_params import (CameraAdapterParams, GpsAdapterParams, ImuAdapterParams, LaserAdapterParams,
                              MagAdapterParams)
from ..nmea_out import NmeaEncoder, open_output
from ..noise import NO_FIX, Latency, adapter_rng, driver_ranges, sensor_models


class Slot:
    """One adapter in its process: its name, its parameters and where its topics are.

    ``name``: the adapter's resolved name (``/imu_adapter``: a standalone node's name, or
    a hosted adapter's name in the host's namespace, so that hosting changes no reading:
    it is its noise stream's id); ``data``: its parameters;
    ``prefix``: what its relative topic names are put under ("" for a standalone node,
    ``imu_adapter/`` in a host)."""

    def __init__(self, name: str, data: Dict[str, Any], prefix: str) -> None:
        self.name, self.data, self.prefix = name, data, prefix

    @property
    def short(self) -> str:
        return self.name.rsplit("/", 1)[-1]

    def params(self, cls, section: str):
        """Its parameters as ``cls``, with the scenario's ``/scenario/<section>`` applied."""
        source = self.name if not self.prefix else rospy.get_name() + "/" + self.short
        return with_scenario(node_params(cls, self.data, source), section)

    def topic(self, name: str) -> str:
        return self.prefix + name

    def rng(self) -> np.random.Generator:
        return adapter_rng(run_seed(), self.name)

    def models(self, kind: str, p):
        """The adapter's (noise, latency), from :func:`quadrivio_sim.noise.sensor_models`."""
        return sensor_models(kind, p, run_seed(), self.name)


class DelayedOutput:
    """Runs publish actions at their delivery time in sim time; never reorders them.

    ``build()`` makes the adapter's noise models and returns its :class:`Latency`; it is
    called at start and again, under the queue's lock, when the clock moves back, so that
    a reading in flight across the jump can neither use the old latency nor queue a
    pre-jump delivery time that would hold every later reading. ``accept(what, stamp,
    *values)`` is the adapter's input check (see module docstring)."""

    def __init__(self, build: Callable[[], Latency], release_period: float) -> None:
        self.build = build
        self.latency = build()
        self.release_period = release_period
        self.queue: Deque[Tuple[float, Callable[[], None]]] = deque()
        self.lock = threading.Lock()
        self.delivered = 0
        self.dropped_at_jumps = 0
        self.guard = input_guard()
        on_clock_jump(self._on_clock_jump)

    def accept(self, what: str, stamp: float, *values: float) -> bool:
        check_clock()
        return self.guard.check(what, stamp, rospy.get_time(), *values)

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        with self.lock:
            self.dropped_at_jumps += len(self.queue)
            self.queue.clear()
            self.latency = self.build()

    def push(self, stamp: float, action: Callable[[], None]) -> None:
        with self.lock:
            if stamp > rospy.get_time() + self.guard.max_future:  # read before the clock moved back
                self.dropped_at_jumps += 1
                return
            if self.latency.zero:
                action()
                self.delivered += 1
                return
            self.queue.append((self.latency.deliver_at(stamp), action))
        self._drain(None)

    def _drain(self, _event=None) -> None:
        # The timer thread and the subscriber thread both drain: popping and publishing
        # under one lock keeps the publication order the queue's order.
        now = rospy.get_time()
        with self.lock:
            while self.queue and self.queue[0][0] <= now + 1e-9:
                _, action = self.queue.popleft()
                action()
                self.delivered += 1

    def _diagnose(self, stat):
        level = DiagnosticStatus.WARN if self.guard.total else DiagnosticStatus.OK
        stat.summary(level, f"{self.delivered} readings delivered, {self.guard.total} rejected")
        stat.add("readings rejected", self.guard.summary())
        stat.add("readings dropped when the clock moved back", str(self.dropped_at_jumps))
        return stat


class Host:
    """The adapters of one process: one delivery timer and one diagnostics updater for
    all of them (each a status of its own, named after the adapter)."""

    def __init__(self) -> None:
        self.outputs: List[DelayedOutput] = []
        self.diag = diagnostics.updater()
        self.diag.setHardwareID(rospy.get_name())

    def output(self, slot: Slot, build: Callable[[], Latency], release_period: float) -> DelayedOutput:
        out = DelayedOutput(build, release_period)
        self.outputs.append(out)
        self.diag.add(slot.short, out._diagnose)  # "imu_adapter", "laser_front", ...
        return out

    def start(self) -> None:
        delayed = [o for o in self.outputs if not o.latency.zero]
        if delayed:
            # In the thread that receives /clock: no thread wake-up per tick just to find
            # (mostly) one reading due; a drain is a few in-place publications
            guarded_timer(min(o.release_period for o in delayed), self._drain, "delayed delivery", inline=True)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")

    def _drain(self, _event) -> None:
        for out in self.outputs:
            out._drain()


def _stamp(t: float) -> rospy.Time:
    return rospy.Time.from_sec(t)


# ------------------------------------------------------------------------ GPS


class GpsAdapter:
    def __init__(self, host: Host, slot: Slot) -> None:
        self.slot = slot
        self.p = slot.params(GpsAdapterParams, "sensors/gps")
        site = site_params()
        self.out = host.output(slot, self._build, self.p.release_period)
        self.frame = site.local_frame()
        self.encoder = NmeaEncoder(self.frame, site.utc_epoch, self.p.nmea.geoid_separation, self.p.nmea.talker)
        try:
            self.nmea = open_output(self.p.nmea.output)
        except (OSError, ValueError) as exc:
            fatal(f"bad parameter ~nmea/output = {self.p.nmea.output!r}: {exc}")
        if self.nmea is not None:
            rospy.loginfo("NMEA output on %s", self.nmea.address)
            rospy.on_shutdown(self.nmea.close)
        self.pub_fix = direct_publisher(slot.topic("gps/fix"), NavSatFix, queue_size=10) if self.p.publish_fix else None
        self.pub_vel = direct_publisher(slot.topic("gps/vel"), TwistStamped, queue_size=10) if self.p.publish_fix else None
        self.input = rospy.resolve_name(slot.topic("sim/gps"))  # remapped: for error messages
        rospy.Subscriber(self.input, RawGps, self._on_raw, queue_size=100)

    def _build(self) -> Latency:
        self.noise, latency = self.slot.models("gps", self.p)
        return latency

    def _on_raw(self, m: RawGps) -> None:
        t = m.header.stamp.to_sec()
        p, v = m.position, m.velocity
        if not self.out.accept(self.input, t, p.x, p.y, p.z, v.x, v.y, v.z):
            return
        r = self.noise.apply(t, (m.position.x, m.position.y, m.position.z), (m.velocity.x, m.velocity.y, m.velocity.z))
        fix = NavSatFix()
        fix.header.stamp = m.header.stamp
        fix.header.frame_id = self.p.frame_id
        fix.status.status = r.status
        fix.status.service = NavSatStatus.SERVICE_GPS
        if r.position is None:
            fix.latitude = fix.longitude = fix.altitude = math.nan
            fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_UNKNOWN
        else:
            fix.latitude, fix.longitude, fix.altitude = self.frame.enu_to_lla(*r.position)
            fix.position_covariance = [r.variances[0], 0.0, 0.0, 0.0, r.variances[1], 0.0, 0.0, 0.0, r.variances[2]]
            fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
        vel = TwistStamped()
        vel.header = fix.header
        vel.twist.linear.x, vel.twist.linear.y = r.velocity[0], r.velocity[1]
        lines = self.encoder.encode(r) if self.nmea is not None else []

        def deliver() -> None:
            if self.pub_fix is not None:
                publish(self.pub_fix, fix)
                if r.status != NO_FIX:
                    publish(self.pub_vel, vel)
            for line in lines:
                self.nmea.write(line + "\r\n")
        self.out.push(t, deliver)


# ------------------------------------------------------------------------ IMU


class ImuAdapter:
    def __init__(self, host: Host, slot: Slot) -> None:
        self.slot = slot
        self.p = slot.params(ImuAdapterParams, "sensors/imu")
        self.out = host.output(slot, self._build, self.p.release_period)
        self.pub = direct_publisher(slot.topic("imu/data"), Imu, queue_size=100)
        self.input = rospy.resolve_name(slot.topic("sim/imu"))  # remapped: for error messages
        rospy.Subscriber(self.input, Imu, self._on_raw, queue_size=200)

    def _build(self) -> Latency:
        self.noise, latency = self.slot.models("imu", self.p)
        return latency

    def _on_raw(self, m: Imu) -> None:
        a, w = m.linear_acceleration, m.angular_velocity
        if not self.out.accept(self.input, m.header.stamp.to_sec(), a.x, a.y, a.z, w.x, w.y, w.z):
            return
        f, g = self.noise.apply((a.x, a.y, a.z), (w.x, w.y, w.z))
        out = Imu()
        out.header.stamp = m.header.stamp
        out.header.frame_id = self.p.frame_id
        out.orientation_covariance[0] = -1.0  # a raw IMU: no orientation estimate (REP-145)
        out.angular_velocity.x, out.angular_velocity.y, out.angular_velocity.z = g
        out.linear_acceleration.x, out.linear_acceleration.y, out.linear_acceleration.z = f
        gv, av = self.noise.gyro_variance, self.noise.accel_variance
        out.angular_velocity_covariance = [gv, 0.0, 0.0, 0.0, gv, 0.0, 0.0, 0.0, gv]
        out.linear_acceleration_covariance = [av, 0.0, 0.0, 0.0, av, 0.0, 0.0, 0.0, av]
        self.out.push(m.header.stamp.to_sec(), lambda: publish(self.pub, out))


# --------------------------------------------------------------- magnetometer


class MagAdapter:
    def __init__(self, host: Host, slot: Slot) -> None:
        self.slot = slot
        self.p = slot.params(MagAdapterParams, "sensors/mag")
        self.out = host.output(slot, self._build, self.p.release_period)
        self.pub = direct_publisher(slot.topic("imu/mag"), MagneticField, queue_size=50)
        self.input = rospy.resolve_name(slot.topic("sim/mag"))  # remapped: for error messages
        rospy.Subscriber(self.input, MagneticField, self._on_raw, queue_size=100)

    def _build(self) -> Latency:
        self.noise, latency = self.slot.models("mag", self.p)
        return latency

    def _on_raw(self, m: MagneticField) -> None:
        h = m.magnetic_field
        if not self.out.accept(self.input, m.header.stamp.to_sec(), h.x, h.y, h.z):
            return
        x, y, z = self.noise.apply((h.x, h.y, h.z))
        out = MagneticField()
        out.header.stamp = m.header.stamp
        out.header.frame_id = self.p.frame_id
        out.magnetic_field.x, out.magnetic_field.y, out.magnetic_field.z = x, y, z
        v = self.p.noise.noise_std ** 2
        out.magnetic_field_covariance = [v, 0.0, 0.0, 0.0, v, 0.0, 0.0, 0.0, v]
        self.out.push(m.header.stamp.to_sec(), lambda: publish(self.pub, out))


# --------------------------------------------------------------------- lasers


class LaserAdapter:
    def __init__(self, host: Host, slot: Slot) -> None:
        self.slot = slot
        self.p = slot.params(LaserAdapterParams, f"sensors/{slot.short}")
        self.out = host.output(slot, self._build, self.p.release_period)
        self.pub = direct_publisher(slot.topic("scan"), LaserScan, queue_size=10)
        self.input = rospy.resolve_name(slot.topic("scan_in"))  # remapped: for error messages
        rospy.Subscriber(self.input, LaserScan, self._on_raw, queue_size=20)

    def _build(self) -> Latency:
        self.noise, latency = self.slot.models("laser", self.p)
        return latency

    def _on_raw(self, m: LaserScan) -> None:
        if not self.out.accept(self.input, m.header.stamp.to_sec(), m.angle_min, m.angle_max, m.angle_increment):
            return
        if self.p.noise.is_silent(m.header.stamp.to_sec()):
            return  # the fault: a dead scanner sends nothing
        out = LaserScan()
        out.header.stamp = m.header.stamp
        out.header.frame_id = self.p.frame_id
        out.angle_min, out.angle_max, out.angle_increment = m.angle_min, m.angle_max, m.angle_increment
        out.time_increment, out.scan_time = m.time_increment, m.scan_time
        out.range_min, out.range_max = m.range_min, m.range_max
        out.ranges = driver_ranges(self.noise.apply(m.ranges, m.range_min, m.range_max), m.range_max, self.p.no_return)
        self.out.push(m.header.stamp.to_sec(), lambda: publish(self.pub, out))


# -------------------------------------------------------------------- cameras


class CameraAdapter:
    def __init__(self, host: Host, slot: Slot) -> None:
        self.slot = slot
        self.p = slot.params(CameraAdapterParams, f"sensors/{slot.short}")
        self.out = host.output(slot, self._build, self.p.release_period)
        self.info = None
        self.pub_image = rospy.Publisher(slot.topic("image_raw"), Image, queue_size=2)
        self.pub_info = rospy.Publisher(slot.topic("camera_info"), CameraInfo, queue_size=2)
        rospy.Subscriber(slot.topic("camera_info_in"), CameraInfo, self._on_info, queue_size=2)
        self.input = rospy.resolve_name(slot.topic("image_in"))  # remapped: for error messages
        rospy.Subscriber(self.input, Image, self._on_image, queue_size=2)

    def _build(self) -> Latency:
        self.rng = self.slot.rng()
        return Latency(self.p.latency, self.rng)

    def _on_info(self, m: CameraInfo) -> None:
        self.info = m

    def _on_image(self, m: Image) -> None:
        if not self.out.accept(self.input, m.header.stamp.to_sec()):
            return
        pixels = np.frombuffer(m.data, dtype=np.uint8).astype(np.float32)
        pixels += self.rng.normal(0.0, self.p.pixel_noise_std, pixels.shape).astype(np.float32)
        out = Image()
        out.header.stamp = m.header.stamp
        out.header.frame_id = self.p.frame_id
        out.height, out.width, out.encoding, out.step, out.is_bigendian = m.height, m.width, m.encoding, m.step, 0
        out.data = np.clip(pixels, 0, 255).astype(np.uint8).tobytes()
        info = self.info

        def deliver() -> None:
            publish(self.pub_image, out)
            if info is not None:
                info.header = out.header
                publish(self.pub_info, info)
        self.out.push(m.header.stamp.to_sec(), deliver)


KINDS = {"gps": GpsAdapter, "imu": ImuAdapter, "mag": MagAdapter, "laser": LaserAdapter, "camera": CameraAdapter}
NODE_KINDS = {"gps_adapter": "gps", "imu_adapter": "imu", "mag_adapter": "mag", "laser_adapter": "laser",
              "camera_adapter": "camera"}


def hosted_slots(params: Dict[str, Any], namespace: str) -> List[Tuple[str, Slot]]:
    """The ``(type, slot)`` of every adapter a host's parameters list (see the module
    docstring); raises ValueError naming what is wrong."""
    entries = params.get("adapters")
    if not isinstance(entries, list) or not entries:
        raise ValueError("~adapters must be a non-empty list of {name: ..., type: ...}")
    slots, seen = [], set()
    for i, entry in enumerate(entries):
        if not isinstance(entry, dict) or set(entry) != {"name", "type"}:
            raise ValueError(f"~adapters[{i}] = {entry!r}: must be {{name: ..., type: ...}} and nothing else")
        name, kind = entry["name"], entry["type"]
        if kind not in KINDS:
            raise ValueError(f"~adapters[{i}]: unknown type {kind!r} (one of {', '.join(sorted(KINDS))})")
        if not isinstance(name, str) or not name or "/" in name or name in seen:
            raise ValueError(f"~adapters[{i}]: name {name!r} must be a plain name, given once")
        seen.add(name)
        data = params.get(name, {})
        if not isinstance(data, dict):
            raise ValueError(f"~{name} must be a dictionary of {kind} adapter parameters, not {data!r}")
        slots.append((kind, Slot(namespace + name, data, name + "/")))
    unused = set(params) - seen - {"adapters"}
    if unused:
        raise ValueError(f"parameters for no listed adapter: ~{', ~'.join(sorted(unused))}")
    return slots


def main(kind: str = "") -> None:
    """``kind`` "": the host (``sensor_adapters``); else one adapter as its own node."""
    # one thread reads every input (/clock's too), released in lockstep
    init_node(kind or "sensor_adapters", receiver=True)
    if kind:
        slots = [(NODE_KINDS[kind], Slot(rospy.get_name(), private_params(), ""))]
    else:
        try:
            slots = hosted_slots(private_params(), rospy.get_namespace())
        except ValueError as exc:
            fatal(f"bad parameter: {exc}")
    host = Host()
    for k, slot in slots:
        KINDS[k](host, slot)
    host.start()
    rospy.spin()
