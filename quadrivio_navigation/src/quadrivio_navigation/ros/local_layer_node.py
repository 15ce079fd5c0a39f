"""Local obstacle layer node: the lasers marked and ray-cleared into a rolling grid around
the vehicle (:mod:`quadrivio_navigation.local_layer`, costmap_2d's obstacle-layer semantics),
for the planner to check its path against and plan around.

Parameters (private, ``config/local_layer.yaml``; a scenario's ``local_layer:`` section
overrides): :class:`quadrivio_navigation.local_layer.LocalLayerParams`, ``~scanners`` (topic,
frame and no_return of each; empty, the default: the guard's, ``~guard_ns``'s ``scanners``
(/guard) with the scenario's ``guard:`` section, so that one list says how each driver reports
no echo), ``~publish_rate`` (Hz, 2), ``~frame_id`` (map),
``~base_frame`` (base_link), ``~terrain_from_scenario`` (bool, true: with a scenario whose
terrain is known, returns on it are the ground, not obstacles), ``~only_with_goal`` (bool,
true: the scanners are subscribed only while ``planner/status`` says the planner pursues a
goal, i.e. is not IDLE; the planner is the layer's reader, and a path-following run spent
0.14 CPU s per simulated second on a layer nobody read). In lockstep the scanners are
subscribed from the start and their scans dropped while the planner is IDLE: lockstep
counts a member's messages from its subscriptions at the start, and a subscription made
mid-run would get the scans its connection happened to be ready for (a planned run would
not repeat).

Subscribes: the scanners' topics (sensor_msgs/LaserScan) and ``localization/predicted``
(nav_msgs/Odometry: where the vehicle is), both while active, ``imu/data`` (sensor_msgs/Imu) and ``vehicle/state``
(quadrivio_plc/VehicleState): roll and pitch (:class:`quadrivio_description.attitude.Attitude`),
with a DEM only, ``/tf_static`` (the scanners' mounts).
Publishes: ``local_obstacles`` (nav_msgs/OccupancyGrid at ``~publish_rate``: 100 marked, 0
seen free, -1 unknown), ``/diagnostics`` (update time, ground returns, rejects).

A scan is dropped and counted, never fatal, when its frame_id is not its scanner's, its
geometry is inconsistent, its stamp is from the future, or no pose or mount is known.
"""

from __future__ import annotations

import math
import threading
import time

import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import OccupancyGrid, Odometry
from sensor_msgs.msg import Imu, LaserScan

from quadrivio_runtime.ros import init_node, lockstep
from quadrivio_description.frames import rotate, yaw_from_quaternion
from quadrivio_runtime.ros import diagnostics
from quadrivio_config import ConfigError, replace_nested
from quadrivio_runtime.ros.params import (fatal, node_params, private_params, split_params, vehicle_params,
                                          with_scenario)
from quadrivio_runtime.ros.timer import check_clock, guarded_timer, input_guard, on_clock_jump, publish
from quadrivio_plc.msg import VehicleState

from quadrivio_description.attitude import Attitude, imu_lever
from ..fields import ScanError, check_scan, rep117_ranges
from ..guard import GuardParams
from ..local_layer import (LocalLayer, LocalLayerNodeParams, LocalLayerParams, scan_in_map, terrain_ground,
                           wheel_centres)
from .site_inputs import StaticFrames, scenario_terrain


NodeParams = LocalLayerNodeParams


def guard_scanners(ns: str):
    """The guard's scanners: ``<ns>/scanners`` (GuardParams' default when the guard has none
    on the parameter server), with the scenario's ``guard:`` section."""
    key = ns.rstrip("/") + "/scanners"
    p = GuardParams()
    if rospy.has_param(key):
        try:
            p = replace_nested(p, {"scanners": rospy.get_param(key)}, key)
        except ConfigError as exc:
            fatal(f"bad parameter: {exc}")
    return with_scenario(p, "guard").scanners


class LocalLayerNode:
    def __init__(self) -> None:
        mine, rest = split_params(private_params(), NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, mine)
        self.p: LocalLayerParams = with_scenario(node_params(LocalLayerParams, rest), "local_layer")
        self.scanners = self.node_params.scanners or guard_scanners(self.node_params.guard_ns)
        rospy.loginfo("local obstacle layer: %s%s", ", ".join(
            s.topic + ("" if s.no_return == "inf" else f" (no echo reported as {s.no_return})") for s in self.scanners),
            "" if self.node_params.scanners else f" (the scanners of {self.node_params.guard_ns})")
        self.vehicle = vehicle_params()
        self.wheels = wheel_centres(self.vehicle)
        self.layer = LocalLayer(self.p)
        self.lock = threading.Lock()
        self.inputs = input_guard()
        self.pose = None  # (stamp, x, y, yaw, horizontal sd)
        self.attitude = Attitude(lever=imu_lever(self.vehicle))  # roll, pitch (the vehicle's own acceleration out)
        self.update_ms = []  # recent update times [ms]
        self.heights = scenario_terrain("local obstacle layer (returns on the terrain are the ground)",
                                        self.node_params.terrain_from_scenario)
        self.frames = StaticFrames(self.node_params.base_frame)
        self.imu_mount = self.vehicle.sensors["imu_link"].rpy if "imu_link" in self.vehicle.sensors else (0, 0, 0)
        if self.heights is not None:
            rospy.Subscriber("imu/data", Imu, self._on_imu, queue_size=20)
            rospy.Subscriber("vehicle/state", VehicleState, self._on_state, queue_size=10)
        self.scan_subs = []
        self.pose_sub = None
        self.active, self.active_since = False, 0.0
        self.fixed_subs = lockstep.member() is not None  # subscribed once (see the module's doc)
        if self.fixed_subs:
            self.pose_sub = rospy.Subscriber("localization/predicted", Odometry, self._on_pose, queue_size=5)
            self.scan_subs = [rospy.Subscriber(s.topic, LaserScan, self._on_scan, s, queue_size=2)
                              for s in self.scanners]
        if self.node_params.only_with_goal:
            from ..msg import PlannerStatus

            rospy.Subscriber("planner/status", PlannerStatus, self._on_planner, queue_size=5)
        else:
            self._activate(True)
        self.pub = rospy.Publisher("local_obstacles", OccupancyGrid, queue_size=2)
        guarded_timer(1.0 / self.node_params.publish_rate, self._publish, "local obstacle grid")
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("local obstacle layer")
        self.diag.add("local obstacle layer", self._diagnose)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        on_clock_jump(self._on_clock_jump)

    def _activate(self, active: bool) -> None:
        """Subscribe the pose and the scanners (or drop them: a message is parsed before any
        callback; the pose at 50 Hz cost an idle layer 0.03 CPU s per simulated second)."""
        if active == self.active:
            return
        self.active = active
        self.active_since = rospy.get_time()
        if self.fixed_subs:  # the subscriptions stay: _on_scan drops what comes while idle
            if not active:
                with self.lock:
                    self.layer = LocalLayer(self.p)
        elif active:
            self.pose_sub = rospy.Subscriber("localization/predicted", Odometry, self._on_pose, queue_size=5)
            self.scan_subs = [rospy.Subscriber(s.topic, LaserScan, self._on_scan, s, queue_size=2)
                              for s in self.scanners]
        else:
            for sub in self.scan_subs + [self.pose_sub]:
                sub.unregister()
            self.scan_subs, self.pose_sub = [], None
            with self.lock:
                self.layer = LocalLayer(self.p)  # what it saw is old by the next goal
                self.pose = None
        rospy.loginfo("local obstacle layer: %s", "reading the scans" if active else "idle: the planner has no goal")

    def _on_planner(self, m) -> None:
        self._activate(m.state != m.IDLE)

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        with self.lock:
            self.layer = LocalLayer(self.p)
            self.pose = None

    def _on_pose(self, m: Odometry) -> None:
        p, q, c = m.pose.pose.position, m.pose.pose.orientation, m.pose.covariance
        if not self.inputs.check("localization/predicted", m.header.stamp.to_sec(), rospy.get_time(), p.x, p.y,
                                 q.z, q.w, c[0], c[7]):
            return
        sd = math.sqrt(max(c[0], c[7], 0.0))
        self.pose = (m.header.stamp.to_sec(), p.x, p.y, yaw_from_quaternion(q.x, q.y, q.z, q.w), sd)

    def _on_imu(self, m: Imu) -> None:
        a, w = m.linear_acceleration, m.angular_velocity
        if not self.inputs.check("imu/data", m.header.stamp.to_sec(), rospy.get_time(), a.x, a.y, a.z, w.x, w.y, w.z):
            return
        self.attitude.add_imu(m.header.stamp.to_sec(), rotate(self.imu_mount, (a.x, a.y, a.z)),
                              rotate(self.imu_mount, (w.x, w.y, w.z)))

    def _on_state(self, m) -> None:
        if self.inputs.check("vehicle/state", m.header.stamp.to_sec(), rospy.get_time(), m.wheel_speed):
            self.attitude.add_speed(m.header.stamp.to_sec(), m.wheel_speed)

    def _on_scan(self, m: LaserScan, s) -> None:
        if not self.active:  # (lockstep: subscribed while the planner is idle)
            return
        check_clock()
        now = rospy.get_time()
        stamp = m.header.stamp.to_sec()
        if m.header.frame_id.lstrip("/") != s.frame:
            self.inputs.reject(s.topic, "wrong frame_id", f"'{m.header.frame_id}', expected '{s.frame}'")
            return
        if not self.inputs.stamp(s.topic, stamp, now):
            return
        try:
            check_scan(len(m.ranges), m.angle_min, m.angle_max, m.angle_increment, m.range_min, m.range_max)
        except ScanError as exc:
            self.inputs.reject(s.topic, "malformed scan", str(exc))
            return
        pose, mount = self.pose, self.frames.mount(s.frame)
        if pose is None and now - self.active_since < self.node_params.max_pose_age:
            return  # just subscribed: the first pose is on its way
        if pose is None or now - pose[0] > self.node_params.max_pose_age:
            self.inputs.reject(s.topic, "no fresh pose", "localization/predicted")
            return
        if mount is None:
            self.inputs.reject(s.topic, "no transform", f"{self.node_params.base_frame} <- {s.frame} on /tf_static")
            return
        t0 = time.perf_counter()
        _, x, y, yaw, sd = pose
        t_b, R_b = mount
        sensor, bearings, ranges = scan_in_map(x, y, yaw, t_b, R_b, m.angle_min, m.angle_increment,
                                               rep117_ranges(m.ranges, m.range_max, s.no_return),
                                               m.range_min, m.range_max)
        ground = None
        if self.heights is not None:
            lp = self.p
            ground = terrain_ground(self.heights, (x, y, yaw, sd), self.attitude.roll, self.attitude.pitch,
                                    self.vehicle.wheel_radius, t_b, R_b, lp.ground_tolerance,
                                    lp.ground_tolerance_per_m, lp.ground_position_sigmas, lp.ground_tolerance_max,
                                    wheels=self.wheels)
        with self.lock:
            self.layer.add_scan(stamp, sensor, bearings, ranges, ground)
        self.update_ms.append(1e3 * (time.perf_counter() - t0))
        del self.update_ms[:-200]

    def _publish(self, _event) -> None:
        with self.lock:
            if not self.layer.placed:
                return
            values = self.layer.grid_values()
            origin = self.layer.origin
        m = OccupancyGrid()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = self.node_params.frame_id
        m.info.map_load_time = m.header.stamp
        m.info.resolution = self.p.resolution
        m.info.width = m.info.height = self.layer.n
        m.info.origin.position.x, m.info.origin.position.y = origin
        m.info.origin.orientation.w = 1.0
        m.data = values.ravel().tolist()
        publish(self.pub, m)

    def _diagnose(self, stat):
        ms = sorted(self.update_ms)
        if not self.active:
            stat.summary(DiagnosticStatus.OK, "idle: the planner has no goal")
            return stat
        stat.summary(DiagnosticStatus.OK if self.pose is not None else DiagnosticStatus.WARN,
                     "updating" if self.pose is not None else "no pose yet")
        if ms:
            stat.add("update p50 / p99 [ms]", f"{ms[len(ms) // 2]:.2f} / {ms[min(len(ms) - 1, int(0.99 * len(ms)))]:.2f}")
        stat.add("marked cells", str(int(self.layer.occupied().sum())))
        stat.add("ground returns", str(self.layer.ground_returns))
        stat.add("inputs rejected", self.inputs.summary())
        return stat


def main() -> None:
    init_node("local_layer")  # joins lockstep when sim.launch lockstep:=true
    LocalLayerNode()
    rospy.spin()
