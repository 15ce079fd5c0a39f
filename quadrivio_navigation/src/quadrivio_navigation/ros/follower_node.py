"""Trajectory follower node: pure pursuit on the predicted pose, setpoints at 50 Hz.

Parameters (private, ``config/follower.yaml``; a scenario's ``follower:`` section
overrides): ``~rate`` (Hz, 50), ``~profile``
(:class:`quadrivio_navigation.paths.SpeedProfileParams`: target speed, lateral
acceleration, acceleration limits), ``~pure_pursuit``
(:class:`quadrivio_navigation.follower.FollowerParams`).

Subscribes: ``planner/path`` (nav_msgs/Path; each pose's orientation is the vehicle's
heading, so a step against it is driven in reverse; a new path replaces the route from
where the vehicle is, continuing from the current setpoints; an empty path stops the
vehicle), ``planner/status`` (quadrivio_navigation/PlannerStatus: when planning for a new
goal fails, the vehicle stops on its current path), ``localization/predicted``
(nav_msgs/Odometry), ``guard/status`` (quadrivio_navigation/GuardStatus: while the
obstacle guard holds the vehicle, standing still is no stall).
Publishes: ``vehicle/setpoint/request`` (quadrivio_plc/Setpoint: the obstacle guard passes it on
to ``vehicle/setpoint/auto``) and ``follower/status``
(quadrivio_navigation/FollowerStatus) at ``~rate`` once a path and a pose exist.

A pose with a non-finite value or a stamp ahead of the clock is dropped (and counted in
``/diagnostics``): the last good pose ages and the follower stops on it, as it does when
poses stop coming. A path with a non-finite pose is refused. When the clock moves back
(the simulator's ``~reset``), the pose is forgotten and the current path is followed
again from its start.
"""

from __future__ import annotations

import math
import threading
from typing import Optional

import numpy as np
import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg

from quadrivio_runtime.ros import init_node
from quadrivio_runtime.ros import diagnostics
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import node_params, vehicle_params, with_scenario
from quadrivio_runtime.ros.timer import check_clock, guarded_timer, input_guard, on_clock_jump, publish
from quadrivio_plc.msg import Setpoint

from ..follower import ABORTED, FOLLOWING, STATUS_NAMES, FollowerConfig, PurePursuit, make_route
from ..msg import FollowerStatus, GuardStatus, PlannerStatus
from .conversions import yaw_of


class FollowerNode:
    def __init__(self) -> None:
        self.p: FollowerConfig = with_scenario(node_params(FollowerConfig), "follower")
        self.vehicle = vehicle_params()
        self.lock = threading.Lock()
        self.pp: Optional[PurePursuit] = None
        self.route = None
        self.guard = input_guard()
        self.pose: Optional[Odometry] = None
        self.last_status = None
        self.last_waiting = False
        self.pub_sp = direct_publisher("vehicle/setpoint/request", Setpoint, queue_size=10)
        self.pub_status = direct_publisher("follower/status", FollowerStatus, queue_size=10)
        rospy.Subscriber("planner/path", PathMsg, self._on_path, queue_size=1)
        rospy.Subscriber("planner/status", PlannerStatus, self._on_planner, queue_size=5)
        rospy.Subscriber("localization/predicted", Odometry, self._on_pose, queue_size=5)
        self.held_until = -1.0  # [s] sim time until which the guard holds the vehicle back
        rospy.Subscriber("guard/status", GuardStatus, self._on_guard, queue_size=5)
        guarded_timer(1.0 / self.p.rate, self._tick, "follower cycle")
        on_clock_jump(self._on_clock_jump)
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("follower")
        self.diag.add("follower", self._diagnose)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        with self.lock:
            self.pose = None
            if self.route is not None:
                self.pp = PurePursuit(self.p.pure_pursuit, self.route, self.vehicle, 0.0, 0.0, None)
                self.pp.set_limits(self.p.profile.accel, self.p.profile.decel)
                self.last_status = None

    def _diagnose(self, stat):
        with self.lock:
            pp = self.pp
        if pp is None:
            stat.summary(DiagnosticStatus.OK, "no path")
        else:
            level = DiagnosticStatus.WARN if pp.status == ABORTED else DiagnosticStatus.OK
            stat.summary(level, STATUS_NAMES[pp.status])
        stat.add("inputs rejected", self.guard.summary())
        return stat

    def _on_path(self, m: PathMsg) -> None:
        with self.lock:
            old = self.pp
            pose = self.pose
        if not m.poses:
            if old is not None:
                old.stop("an empty path: stopping")
                rospy.logwarn("empty path received: stopping")
            return
        poses = np.array([(ps.pose.position.x, ps.pose.position.y, yaw_of(ps.pose.orientation)) for ps in m.poses])
        if not np.all(np.isfinite(poses)):
            bad = int(np.argmax(~np.all(np.isfinite(poses), axis=1)))
            self.guard.reject("planner/path", "value not finite", f"pose {bad} of {len(poses)}")
            rospy.logerr("ignored a path of %d poses: pose %d is not finite", len(poses), bad)
            return
        speed = pose.twist.twist.linear.x if pose is not None else 0.0
        if old is None or old.status != FOLLOWING or not math.isfinite(speed):
            speed = 0.0
        pp_params = self.p.pure_pursuit
        try:
            route = make_route(poses, self.p.profile, pp_params.reverse_speed, v_start=speed)
        except ValueError as exc:
            rospy.logerr("ignored a path of %d poses: %s", len(m.poses), exc)
            if old is not None:
                old.stop(f"unusable path: {exc}")
            return
        with self.lock:
            last_sp = (old.sp_speed, old.sp_handlebar, old.t_last) if old is not None and old.status == FOLLOWING else \
                (0.0, 0.0, None)
            self.pp = PurePursuit(pp_params, route, self.vehicle, *last_sp)
            self.route = route
            self.pp.set_limits(self.p.profile.accel, self.p.profile.decel)
            self.last_status = None
        cusps = len(route.segments) - 1
        rospy.loginfo("following a path of %.1f m (%d cusp%s) at up to %.1f m/s", route.length, cusps,
                      "" if cusps == 1 else "s", max(float(s.path.v.max()) for s in route.segments))

    def _on_planner(self, m: PlannerStatus) -> None:
        if m.state == PlannerStatus.FAILED:
            with self.lock:
                pp = self.pp
            if pp is not None and pp.status == FOLLOWING:
                pp.stop(f"planner failed: {m.reason}")
                rospy.logwarn("planning for the new goal failed: stopping (%s)", m.reason)

    def _on_guard(self, m: GuardStatus) -> None:
        # Held below the follower's own floor: no progress is the guard's doing, not a stall
        # (for a guard status period and a bit: statuses come with every scan, 10-20 Hz)
        if m.action in (GuardStatus.STOP, GuardStatus.HOLD, GuardStatus.FAULT) or \
                m.speed_limit < self.p.pure_pursuit.min_speed:
            self.held_until = m.header.stamp.to_sec() + 0.3

    def _on_pose(self, m: Odometry) -> None:
        check_clock()
        p = m.pose.pose.position
        q = m.pose.pose.orientation
        if not self.guard.check("localization/predicted", m.header.stamp.to_sec(), rospy.get_time(),
                                p.x, p.y, q.x, q.y, q.z, q.w, m.twist.twist.linear.x):
            return
        with self.lock:
            self.pose = m

    def _tick(self, _event) -> None:
        with self.lock:
            pp, pose = self.pp, self.pose
            if pp is None or pose is None:
                return
            now = rospy.Time.now()
            age = max(0.0, (now - pose.header.stamp).to_sec())
            p = pose.pose.pose.position
            values = (p.x, p.y, yaw_of(pose.pose.pose.orientation), pose.twist.twist.linear.x)
            if not all(map(math.isfinite, values)):
                c = pp.abort("the predicted pose is not finite")
            else:
                c = pp.update(*values, pose_age=age, t=now.to_sec(), held=now.to_sec() <= self.held_until)
        sp = Setpoint()
        sp.header.stamp = now
        sp.speed, sp.handlebar, sp.brake = c.speed, c.handlebar, c.brake
        if not publish(self.pub_sp, sp):
            return
        st = FollowerStatus()
        st.header.stamp = now
        st.status, st.cross_track, st.progress = c.status, c.cross_track, c.progress
        st.remaining = c.remaining if math.isfinite(c.remaining) else 0.0
        st.reason = c.reason
        st.segment, st.direction = c.segment, c.direction
        publish(self.pub_status, st)
        if c.status != self.last_status:
            (rospy.logwarn if c.status == ABORTED else rospy.loginfo)(
                "follower %s%s", STATUS_NAMES[c.status], f": {c.reason}" if c.reason else "")
            self.last_status = c.status
        waiting = bool(pp.waiting_pose)
        if waiting != self.last_waiting:
            if waiting:
                rospy.logwarn("follower: stopped, %s", pp.waiting_pose)
            else:
                rospy.loginfo("follower: a fresh pose again: driving on")
            self.last_waiting = waiting


def main() -> None:
    init_node("follower")  # joins lockstep when sim.launch lockstep:=true
    FollowerNode()
    rospy.spin()
