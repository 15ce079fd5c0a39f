"""Localization node: the fixed-lag smoother with online self-calibration (ROAMFREE's role).

Parameters (private, ``config/localization.yaml``): every key of
:class:`quadrivio_localization.smoother.LocalizerParams`, and ``~map_frame`` (map),
``~odom_frame`` (odom), ``~base_frame`` (base_link), ``~publish_tf`` (true),
``~calibration_period`` (s, 1.0). Vehicle geometry from ``/vehicle``, the datum and the
Earth's field from ``/site``.

Subscribes: ``gps/fix`` (NavSatFix), ``imu/data`` (Imu), ``imu/mag`` (MagneticField),
``vehicle/state`` (quadrivio_plc/VehicleState).
Publishes: ``localization/odom`` (nav_msgs/Odometry, map -> base_link, at ``~rate``,
stamped with the keyframe time), ``localization/calibration``
(quadrivio_localization/Calibration, every ``~calibration_period``), TF ``map -> odom``
and ``odom -> base_link`` (dead reckoning on the calibrated model), ``/diagnostics``.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass

import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, MagneticField, NavSatFix

from quadrivio_runtime.ros import init_node
from quadrivio_description.frames import quaternion_from_yaw
from quadrivio_description.kinematics import max_delta
from quadrivio_config import param
from quadrivio_runtime.ros import diagnostics
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import (node_params, private_params, site_params, split_params,
                                             vehicle_params, with_scenario)
from quadrivio_runtime.ros.timer import (check_clock, guarded_timer, input_guard, on_clock_jump, publish,
                                         send_transform)
from quadrivio_plc.msg import VehicleState

from ..dead_reckoning import DeadReckoning
from ..msg import Calibration, GpsDecision
from ..smoother import Localizer, LocalizerParams
from . import messages


@dataclass(frozen=True)
class NodeParams:
    map_frame: str = param("map")
    odom_frame: str = param("odom")
    base_frame: str = param("base_link")
    publish_tf: bool = param(True, doc="publish map -> odom -> base_link")
    calibration_period: float = param(1.0, lo=0.05, hi=60.0, unit="s", doc="period of localization/calibration")
    max_future: float = param(0.5, lo=0.0, hi=60.0, unit="s",
                              doc="inputs stamped further ahead of the clock are rejected (and counted)")


class LocalizationNode:
    def __init__(self) -> None:
        mine, rest = split_params(private_params(), NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, mine)
        self.p: LocalizerParams = with_scenario(node_params(LocalizerParams, rest), "localization")
        self.vehicle, self.site = vehicle_params(), site_params()
        self.lock = threading.Lock()  # the smoother is fed from subscriber threads, updated on the timer
        self.guard = input_guard(self.node_params.max_future)
        self.resets = 0
        self._fresh_state()
        self.pub_odom = direct_publisher("localization/odom", Odometry, queue_size=20)
        self.pub_cal = rospy.Publisher("localization/calibration", Calibration, queue_size=5, latch=True)
        # every GPS fix's fate: used, or why not (analyze marks the rejected ones)
        self.pub_decisions = rospy.Publisher("localization/gps_decisions", GpsDecision, queue_size=100)
        self.tf = tf2_ros.TransformBroadcaster() if self.node_params.publish_tf else None
        self.update_ms = []
        on_clock_jump(self._on_clock_jump)
        rospy.Subscriber("vehicle/state", VehicleState, self._on_state, queue_size=100)
        rospy.Subscriber("imu/data", Imu, self._on_imu, queue_size=200)
        rospy.Subscriber("imu/mag", MagneticField, self._on_mag, queue_size=100)
        rospy.Subscriber("gps/fix", NavSatFix, self._on_gps, queue_size=20)
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("localization")
        self.diag.add("localization", self._diagnose)
        guarded_timer(1.0 / self.p.rate, self._tick, "localization update")
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")

    def _fresh_state(self) -> None:
        self.loc = Localizer(self.p, self.vehicle, self.site)
        self.dr = DeadReckoning(self.vehicle.wheelbase, self.vehicle.steering.ratio, max_delta(self.vehicle))
        self.estimate = None
        self.last_cal = -math.inf

    def _on_clock_jump(self, before: float, now: float) -> None:
        with self.lock:
            self._fresh_state()
            self.resets += 1
        rospy.logwarn("localization restarted: the clock moved back from %.3f s to %.3f s", before, now)

    def _accept(self, what: str, stamp: float, *values: float) -> bool:
        check_clock()
        return self.guard.check(what, stamp, rospy.get_time(), *values)

    # --------------------------------------------------------------- inputs
    def _on_state(self, m: VehicleState) -> None:
        t = m.header.stamp.to_sec()
        if m.faults & VehicleState.FAULT_LINK:
            self.guard.counts[("vehicle/state", "PLC link down")] += 1
            return
        if not self._accept("vehicle/state", t, m.wheel_speed, m.handlebar):
            return
        with self.lock:
            messages.add_state(self.loc, m)
            x, y, th = self.dr.add(t, m.wheel_speed, m.handlebar)
        if self.tf is not None and math.isfinite(x):
            tr = TransformStamped()
            tr.header.stamp = m.header.stamp
            tr.header.frame_id, tr.child_frame_id = self.node_params.odom_frame, self.node_params.base_frame
            tr.transform.translation.x, tr.transform.translation.y = x, y
            q = tr.transform.rotation
            q.x, q.y, q.z, q.w = quaternion_from_yaw(th)
            send_transform(self.tf, tr)

    def _on_imu(self, m: Imu) -> None:
        a, w = m.linear_acceleration, m.angular_velocity
        if not self._accept("imu/data", m.header.stamp.to_sec(), a.x, a.y, a.z, w.x, w.y, w.z):
            return
        with self.lock:
            messages.add_imu(self.loc, m)

    def _on_mag(self, m: MagneticField) -> None:
        f = m.magnetic_field
        if not self._accept("imu/mag", m.header.stamp.to_sec(), f.x, f.y, f.z):
            return
        with self.lock:
            messages.add_mag(self.loc, m)

    def _on_gps(self, m: NavSatFix) -> None:
        if m.status.status >= 0 and not self._accept("gps/fix", m.header.stamp.to_sec(), m.latitude, m.longitude):
            return
        if m.status.status < 0 and not self._accept("gps/fix", m.header.stamp.to_sec()):
            return
        with self.lock:
            messages.add_gps(self.loc, m)

    # --------------------------------------------------------------- output
    def _tick(self, _event) -> None:
        now = rospy.get_time()
        w0 = time.perf_counter()
        with self.lock:
            try:
                est = self.loc.update(now)
            except RuntimeError as exc:  # a numerically failed update must not end localization
                rospy.logerr_throttle(5.0, "smoother update failed (%s); restarting from the next fix", exc)
                self.loc = Localizer(self.p, self.vehicle, self.site)
                return
            sigma = self.loc.calibration_sigma() if now - self.last_cal >= self.node_params.calibration_period else None
            events = self.loc.pop_events()
            decisions = self.loc.pop_gps_decisions()
        for d in decisions:
            publish(self.pub_decisions, messages.gps_decision(*d))
        for e in events:
            rospy.logwarn("localization: %s", e)
        self.update_ms.append((time.perf_counter() - w0) * 1e3)
        self.update_ms = self.update_ms[-1000:]
        if est is None:
            rospy.loginfo_throttle(10.0, "localization waiting for a GPS fix and the magnetometer")
            return
        self.estimate = est
        with self.lock:  # the state subscriber integrates with dr.calib and appends to its history
            self.dr.calib = (est.calibration["wheel_speed_scale"], est.calibration["handlebar_offset"],
                             est.calibration["steering_gain"])
            odom = self.dr.pose_at(est.stamp) if self.tf is not None else None
        stamp = rospy.Time.from_sec(est.stamp)
        m = messages.odometry(est, self.node_params.map_frame, self.node_params.base_frame)
        self.pub_odom.publish(m)
        if odom is not None:
            self._publish_map_to_odom(est, odom, stamp)
        if sigma is not None:
            self.last_cal = now
            self._publish_calibration(est, sigma, stamp)

    def _publish_map_to_odom(self, est, odom, stamp) -> None:
        # T_map_odom = T_map_base * T_odom_base^-1 (planar)
        ox, oy, oth = odom
        th = est.theta - oth
        c, s = math.cos(th), math.sin(th)
        tr = TransformStamped()
        tr.header.stamp = stamp
        tr.header.frame_id, tr.child_frame_id = self.node_params.map_frame, self.node_params.odom_frame
        tr.transform.translation.x = est.x - (c * ox - s * oy)
        tr.transform.translation.y = est.y - (s * ox + c * oy)
        q = tr.transform.rotation
        q.x, q.y, q.z, q.w = quaternion_from_yaw(th)
        send_transform(self.tf, tr)

    def _publish_calibration(self, est, sigma, stamp) -> None:
        self.pub_cal.publish(messages.calibration(est, sigma))

    def _diagnose(self, stat):
        c = self.loc.counters
        if self.estimate is None:
            stat.summary(DiagnosticStatus.WARN, "waiting for a GPS fix and the magnetometer")
        elif rospy.get_time() - self.estimate.stamp > 1.0:
            stat.summary(DiagnosticStatus.ERROR, "no new keyframe for more than 1 s")
        else:
            sd = math.sqrt(max(self.estimate.covariance[0, 0], self.estimate.covariance[1, 1]))
            stat.summary(DiagnosticStatus.OK, f"tracking, position sigma {sd:.2f} m")
        faults = self.loc.faults()
        if faults:
            stat.summary(DiagnosticStatus.WARN, "; ".join(faults))
        ups = sorted(self.update_ms) or [math.nan]
        for key, value in (("magnetometer calibration", self.p.priors.magnetometer.source),
                           ("keyframes", c.keyframes), ("GPS fixes used", c.gps_used),
                           ("GPS fixes not used", self.loc.gate.summary()),
                           *((f"GPS fixes not used: {r}", n) for r, n in self.loc.gate.counts.items()),
                           ("magnetometer factors", c.mag_used),
                           ("magnetometer slots skipped at rest", c.mag_skipped_at_rest),
                           ("magnetometer readings later than max_wait (dropped)", c.mag_late),
                           ("intervals without odometry", c.intervals_without_odometry),
                           ("intervals without gyro", c.intervals_without_gyro),
                           ("intervals with the wheel speed ignored (read 0 while moving)",
                            c.intervals_wheel_rejected),
                           ("intervals with the wheel locked (its speed dropped faster than wheel_lock_decel)",
                            c.intervals_wheel_locked),
                           ("bad or out-of-order inputs", c.bad_input + c.out_of_order),
                           ("inputs rejected by the node", self.guard.summary()),
                           ("restarts after the clock moved back", self.resets),
                           ("update p50 [ms]", f"{ups[len(ups) // 2]:.2f}"),
                           ("update p99 [ms]", f"{ups[min(len(ups) - 1, int(0.99 * len(ups)))]:.2f}")):
            stat.add(key, str(value))
        return stat


def main() -> None:
    init_node("localization")  # joins lockstep when sim.launch lockstep:=true
    LocalizationNode()
    rospy.spin()
