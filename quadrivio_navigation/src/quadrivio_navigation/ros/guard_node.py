"""Obstacle guard node: the protective stop between the follower and the PLCClient.

In AUTO the PLCClient takes only this node's setpoints: the follower and the excitation
program *request* on ``vehicle/setpoint/request``; the guard passes each request on to
``vehicle/setpoint/auto``, limited by what the lasers see (:mod:`quadrivio_navigation.guard`:
protective and warning fields computed from the speed, the handlebar, the stopping
distance and the slope), and sends a stop at once, without waiting for the next
request, when a scan shows something inside the protective field.

Parameters (private, ``config/guard.yaml``; a scenario's ``guard:`` section overrides):
the fields of :class:`quadrivio_navigation.guard.GuardParams`, and ``~zone_file`` (str,
"": a YAML file with ``zone: [[x, y], ...]`` in the map frame, the operating zone, when
the parameters give none), ``~terrain_from_scenario`` (bool, true) and ``~ground_tolerance``
(m, 0.15): with a scenario whose terrain is known (a DEM), a return within the tolerance of
it, from the laser's 3D pose (the predicted pose, the DEM's height there, roll and pitch
from :class:`quadrivio_description.attitude.Attitude`), is the ground, not an obstacle.

Subscribes: ``vehicle/setpoint/request`` (quadrivio_plc/Setpoint), each scanner's topic
(sensor_msgs/LaserScan; ``scan/front``, ``scan/rear``), ``vehicle/state``
(quadrivio_plc/VehicleState: the measured speed and handlebar), ``imu/data``
(sensor_msgs/Imu: the slope), ``localization/predicted`` (nav_msgs/Odometry, with an
operating zone or a DEM only), ``/tf_static`` (the scanners' mounts: a scanner whose frame is not
on it stops the vehicle).
Publishes: ``vehicle/setpoint/auto`` (quadrivio_plc/Setpoint), ``guard/status``
(quadrivio_navigation/GuardStatus: every scan and every change of action),
``/diagnostics``.

Bad input is counted and dropped, never fatal: a scan with a frame_id other than its
scanner's, inconsistent geometry (sizes, a zero increment), a stamp from the future or
older than ``max_scan_age``; a request or state with a non-finite value. A dropped scan
is a missing one: the scanner falls silent and the vehicle stops.
"""

from __future__ import annotations

import math
import threading

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, LaserScan

from quadrivio_runtime.ros import init_node
from quadrivio_config import ConfigError, replace_nested
from quadrivio_description.frames import rotate, yaw_from_quaternion
from quadrivio_runtime.ros import diagnostics
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import fatal, node_params, private_params, split_params, vehicle_params, \
    with_scenario
from quadrivio_runtime.ros.timer import check_clock, guarded_timer, input_guard, on_clock_jump, publish
from quadrivio_plc.msg import Setpoint, VehicleState

from quadrivio_description.attitude import Attitude, imu_lever
from ..fields import ScanError, check_scan, rep117_ranges, scan_points
from ..local_layer import scan_ground, terrain_ground, wheel_centres
from ..guard import (ACTION_NAMES, CLEAR, FAULT, HOLD, SLOW, STOP, DecisionLog, Guard, GuardNodeParams, GuardParams,
                     load_zone_file)
from ..msg import GuardStatus
from .site_inputs import StaticFrames, scenario_heightfield

MAX_RANGE = 20.0  # [m] returns beyond this cannot matter for the fields (warning field at 8 m/s: ~16 m)


NodeParams = GuardNodeParams


def guard_config(private: dict, source: str):
    """The guard's configuration from its private parameters (``source``: the node's name,
    for messages), the scenario's ``guard:`` section, the zone file, the vehicle and the
    scenario's terrain: ``(GuardParams, NodeParams, VehicleParams, Heightfield or None)``.
    Stops the process with a FATAL message on a bad value. The Python node and the roscpp
    node (through :mod:`quadrivio_navigation.ros.guard_config`) read it here alike."""
    mine, rest = split_params(private, NodeParams)
    node = node_params(NodeParams, mine, source)
    try:
        p: GuardParams = with_scenario(node_params(GuardParams, rest, source), "guard")
        if node.zone_file and not p.zone:
            p = replace_nested(p, {"zone": [list(v) for v in load_zone_file(node.zone_file)]}, "~zone_file")
    except ConfigError as exc:
        fatal(f"bad guard parameter: {exc}")
    hf = scenario_heightfield("obstacle guard (returns on the terrain are the ground)", node.terrain_from_scenario)
    return p, node, vehicle_params(), hf


class GuardNode:
    def __init__(self) -> None:
        p, self.node_params, self.vehicle, hf = guard_config(private_params(), rospy.get_name())
        self.p = p
        self.heights = None if hf is None else hf.heights
        self.core = Guard(p, self.vehicle, self.heights)
        self.wheels = wheel_centres(self.vehicle)
        self.imu_mount = self.vehicle.sensors["imu_link"].rpy if "imu_link" in self.vehicle.sensors else (0, 0, 0)
        self.attitude = Attitude(p.slope_tau, lever=imu_lever(self.vehicle))
        self.pose = None  # (stamp, x, y, yaw, horizontal sd) from localization/predicted
        self.ground_returns = 0
        self.lock = threading.Lock()
        self.inputs = input_guard(max_future=p.max_future)
        self.request = None  # (received at, speed, handlebar, brake)
        self.frames = StaticFrames(self.node_params.base_frame)
        self.last_action = None
        self.log = DecisionLog()
        self.pub_sp = direct_publisher("vehicle/setpoint/auto", Setpoint, queue_size=10)
        self.pub_status = direct_publisher("guard/status", GuardStatus, queue_size=20)
        rospy.Subscriber("vehicle/setpoint/request", Setpoint, self._on_request, queue_size=10)
        rospy.Subscriber("vehicle/state", VehicleState, self._on_state, queue_size=10)
        rospy.Subscriber("imu/data", Imu, self._on_imu, queue_size=20)
        for s in p.scanners:
            rospy.Subscriber(s.topic, LaserScan, self._on_scan, s, queue_size=2)
        if p.zone or self.heights is not None:
            rospy.Subscriber("localization/predicted", Odometry, self._on_pose, queue_size=5)
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("obstacle guard")
        self.diag.add("obstacle guard", self._diagnose)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        on_clock_jump(self._on_clock_jump)
        rospy.loginfo("obstacle guard: %s; brake %.1f m/s^2 after %.2f s, margins %.2f / %.2f m%s",
                      ", ".join(f"{s.topic} ({s.covers}"
                                + ("" if s.no_return == "inf" else f", no echo reported as {s.no_return}") + ")"
                                for s in p.scanners), p.brake_decel, p.brake_latency,
                      p.margin, p.warning_margin, f", operating zone of {len(p.zone)} vertices" if p.zone else "")

    def _ground(self, m: LaserScan, ranges, mount, now: float):
        """Which of the scan's ``ranges`` lie on the DEM (None: no DEM, or no fresh pose)."""
        pose = self.pose
        if self.heights is None or pose is None or now - pose[0] > 0.5:
            return None
        n = self.node_params
        ground = terrain_ground(self.heights, pose[1:], self.attitude.roll, self.attitude.pitch,
                                self.vehicle.wheel_radius, (mount[0], mount[1], mount[4]), mount[3],
                                n.ground_tolerance, 0.0, n.ground_position_sigmas, n.ground_tolerance_max,
                                n.ground_position_sd_min, self.wheels)
        return scan_ground(ground, ranges, m.angle_min, m.angle_increment, m.range_min, m.range_max, MAX_RANGE)

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        with self.lock:
            self.core = Guard(self.p, self.vehicle, self.heights)
            self.attitude = Attitude(self.p.slope_tau, lever=imu_lever(self.vehicle))
            self.request = None
            self.last_action = None

    # ---------------------------------------------------------------- inputs
    def _mount(self, frame: str):
        """The frame's (x, y, yaw, rotation, z) in base_link through /tf_static; None if unknown."""
        got = self.frames.mount(frame)
        if got is None:
            return None
        t, R = got
        return float(t[0]), float(t[1]), math.atan2(R[1, 0], R[0, 0]), R, float(t[2])

    def _on_state(self, m: VehicleState) -> None:
        check_clock()
        if not self.inputs.check("vehicle/state", m.header.stamp.to_sec(), rospy.get_time(), m.wheel_speed,
                                 m.handlebar):
            return
        with self.lock:
            self.core.on_state(m.header.stamp.to_sec(), m.wheel_speed, m.handlebar)
            self.attitude.add_speed(m.header.stamp.to_sec(), m.wheel_speed)

    def _on_imu(self, m: Imu) -> None:
        a, w = m.linear_acceleration, m.angular_velocity
        if not self.inputs.check("imu/data", m.header.stamp.to_sec(), rospy.get_time(), a.x, a.y, a.z, w.x, w.y,
                                 w.z):
            return
        f = rotate(self.imu_mount, (a.x, a.y, a.z))
        g = rotate(self.imu_mount, (w.x, w.y, w.z))
        with self.lock:
            self.attitude.add_imu(m.header.stamp.to_sec(), f, g)
            self.core.on_pitch(m.header.stamp.to_sec(), self.attitude.pitch)

    def _on_pose(self, m: Odometry) -> None:
        p, q = m.pose.pose.position, m.pose.pose.orientation
        c = m.pose.covariance
        if not self.inputs.check("localization/predicted", m.header.stamp.to_sec(), rospy.get_time(), p.x, p.y,
                                 q.z, q.w, c[0], c[7]):
            return
        sd = math.sqrt(max(c[0], c[7], 0.0))
        yaw = yaw_from_quaternion(q.x, q.y, q.z, q.w)
        self.pose = (m.header.stamp.to_sec(), p.x, p.y, yaw, sd)
        with self.lock:
            self.core.on_pose(m.header.stamp.to_sec(), p.x, p.y, yaw, sd)

    def _on_scan(self, m: LaserScan, s) -> None:
        check_clock()
        now = rospy.get_time()
        stamp = m.header.stamp.to_sec()
        what = s.topic
        if m.header.frame_id.lstrip("/") != s.frame:
            self.inputs.reject(what, "wrong frame_id", f"'{m.header.frame_id}', expected '{s.frame}'")
            return
        if not self.inputs.stamp(what, stamp, now):
            return
        if now - stamp > self.p.max_scan_age:
            self.inputs.reject(what, "stale scan", f"{now - stamp:.3f} s old (> {self.p.max_scan_age} s)")
            return
        try:
            check_scan(len(m.ranges), m.angle_min, m.angle_max, m.angle_increment, m.range_min, m.range_max)
        except ScanError as exc:
            self.inputs.reject(what, "malformed scan", str(exc))
            return
        mount = self._mount(s.frame)
        if mount is None:
            points, error = None, f"no transform {self.node_params.base_frame} <- {s.frame} on /tf_static"
        else:
            ranges = rep117_ranges(m.ranges, m.range_max, s.no_return)  # the driver's "nothing seen" as +inf
            ground = self._ground(m, ranges, mount, now)
            if ground is not None and ground.any():  # the ground: nothing there (REP 117's +inf)
                ranges = np.where(ground, np.inf, ranges)
                self.ground_returns += int(ground.sum())
            points = scan_points(ranges, m.angle_min, m.angle_increment, m.range_min, m.range_max, mount[:3],
                                 MAX_RANGE, mount[3])
            error = ""
        with self.lock:
            self.core.on_scan(what, stamp, points, error)
            req = self.request
            fresh = req is not None and now - req[0] <= self.node_params.request_timeout
            speed, handlebar, brake = (req[1], req[2], req[3]) if fresh else (0.0, 0.0, 0.0)
            d = self.core.decide(now, speed, handlebar)
            stop_now = fresh and d.action in (STOP, FAULT) and self.last_action not in (STOP, FAULT)
            sp = self.core.command(d, speed, handlebar, brake)
            before, self.last_action = self.last_action, d.action
        if stop_now:  # at once: the next request may be 20 ms away
            self._send(sp, rospy.Time.from_sec(now))
        self._status(d, speed, sp.speed, before, handlebar)

    def _on_request(self, m: Setpoint) -> None:
        check_clock()
        now = rospy.get_time()
        if not self.inputs.check("vehicle/setpoint/request", m.header.stamp.to_sec(), now, m.speed, m.handlebar,
                                 m.brake):
            return
        with self.lock:
            self.request = (now, m.speed, m.handlebar, m.brake)
            d = self.core.decide(now, m.speed, m.handlebar)
            sp = self.core.command(d, m.speed, m.handlebar, m.brake)
            before, self.last_action = self.last_action, d.action
        self._send(sp, m.header.stamp)
        if d.action != before:
            self._status(d, m.speed, sp.speed, before, m.handlebar)

    # --------------------------------------------------------------- outputs
    def _send(self, sp, stamp) -> None:
        out = Setpoint()
        out.header.stamp = stamp
        out.speed, out.handlebar, out.brake = sp.speed, sp.handlebar, sp.brake
        publish(self.pub_sp, out)

    def _status(self, d, requested: float, commanded: float, before, handlebar: float) -> None:
        """Publish the decision; log a change of action (``before``: the previous one)."""
        core = self.core
        m = GuardStatus()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = self.node_params.base_frame
        m.action, m.field, m.reason = d.action, d.field, d.reason
        m.speed_limit = d.limit
        m.requested_speed, m.commanded_speed = requested, commanded
        m.measured_speed = core.state[1] if core.state is not None else math.nan
        m.requested_handlebar = handlebar
        m.measured_handlebar = core.state[2] if core.state is not None else math.nan
        m.free_distance, m.protective_distance, m.warning_distance = d.free, d.protective, d.warning
        if d.nearest is not None:
            m.has_nearest = True
            m.nearest.x, m.nearest.y = d.nearest
        m.scanner = d.scanner
        if math.isfinite(d.scan_stamp):
            m.scan_stamp = rospy.Time.from_sec(d.scan_stamp)
        m.direction, m.slope = d.direction, d.slope
        m.protective_stops = core.protective_stops
        publish(self.pub_status, m)
        if self.log.worth(rospy.get_time(), d.action, before, d.reason):
            log = rospy.logerr if d.action == FAULT else rospy.logwarn if d.action in (STOP, HOLD) else rospy.loginfo
            log("guard %s%s", ACTION_NAMES[d.action], f": {d.reason}" if d.reason else "")

    def _diagnose(self, stat):
        with self.lock:
            d, core = self.core.last, self.core
        if d is None:
            stat.summary(DiagnosticStatus.OK, "no request yet")
        else:
            level = {CLEAR: DiagnosticStatus.OK, SLOW: DiagnosticStatus.OK, HOLD: DiagnosticStatus.WARN,
                     STOP: DiagnosticStatus.WARN, FAULT: DiagnosticStatus.ERROR}[d.action]
            stat.summary(level, f"{ACTION_NAMES[d.action]}{': ' + d.reason if d.reason else ''}")
            stat.add("field", d.field or "none")
            stat.add("free distance [m]", f"{d.free:.2f}")
            stat.add("protective field [m]", f"{d.protective:.2f}")
            stat.add("warning field [m]", f"{d.warning:.2f}")
            stat.add("speed limit [m/s]", f"{d.limit:.2f}")
            stat.add("nearest point (base_link) [m]", "none" if d.nearest is None else
                     f"{d.nearest[0]:.2f}, {d.nearest[1]:.2f} ({d.scanner})")
            stat.add("slope used [deg]", f"{math.degrees(d.slope):.1f}")
        stat.add("protective stops", str(core.protective_stops))
        stat.add("fail-safe stops", str(core.fault_stops))
        stat.add("zone stops", str(core.zone_stops))
        stat.add("moving obstacles", ", ".join(
            f"{topic}: {tr.prediction.moving} moving of {len(tr.tracks)} tracked" for topic, tr in core.trackers.items()))
        # tracks whose centroid slid like a moving thing's, refused for want of seen-through evidence
        stat.add("standing things refused as moving", ", ".join(
            f"{topic}: {tr.refused}" for topic, tr in core.trackers.items()))
        stat.add("ground returns (DEM)", str(self.ground_returns) if self.heights is not None else "no DEM")
        stat.add("inputs rejected", self.inputs.summary())
        return stat


def main() -> None:
    init_node("guard")  # joins lockstep when sim.launch lockstep:=true
    GuardNode()
    rospy.spin()
