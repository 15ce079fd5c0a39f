"""Trajectory follower node: pure pursuit on the predicted pose, setpoints at 50 Hz.

Parameters (private, ``config/follower.yaml``; a scenario's ``follower:`` section
overrides): ``~rate`` (Hz, 50), ``~profile``
(:class:`quadrivio_navigation.paths.SpeedProfileParams`: target speed, lateral
acceleration, acceleration limits), ``~pure_pursuit``
(:class:`quadrivio_navigation.follower.FollowerParams`).

Subscribes: ``planner/path`` (nav_msgs/Path; a new path restarts the follower),
``localization/predicted`` (nav_msgs/Odometry).
Publishes: ``vehicle/setpoint/auto`` (quadrivio_plc/Setpoint) and ``follower/status``
(quadrivio_navigation/FollowerStatus) at ``~rate`` once a path and a pose exist.
"""

from __future__ import annotations

import math
import threading
from typing import Optional

import numpy as np
import rospy
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg

from quadrivio_description.ros.params import node_params, vehicle_params, with_scenario
from quadrivio_plc.msg import Setpoint
from quadrivio_description.ros.timer import guarded_timer

from ..follower import ABORTED, STATUS_NAMES, FollowerConfig, PurePursuit
from ..msg import FollowerStatus
from ..paths import make_path


class FollowerNode:
    def __init__(self) -> None:
        self.p: FollowerConfig = with_scenario(node_params(FollowerConfig), "follower")
        self.vehicle = vehicle_params()
        self.lock = threading.Lock()
        self.pp: Optional[PurePursuit] = None
        self.pose: Optional[Odometry] = None
        self.last_status = None
        self.pub_sp = rospy.Publisher("vehicle/setpoint/auto", Setpoint, queue_size=10)
        self.pub_status = rospy.Publisher("follower/status", FollowerStatus, queue_size=10)
        rospy.Subscriber("planner/path", PathMsg, self._on_path, queue_size=1)
        rospy.Subscriber("localization/predicted", Odometry, self._on_pose, queue_size=5)
        guarded_timer(1.0 / self.p.rate, self._tick, "follower cycle")

    def _on_path(self, m: PathMsg) -> None:
        pts = np.array([(ps.pose.position.x, ps.pose.position.y) for ps in m.poses])
        try:
            path = make_path(pts, self.p.profile)
        except ValueError as exc:
            rospy.logerr("ignored a path of %d poses: %s", len(m.poses), exc)
            return
        with self.lock:
            self.pp = PurePursuit(self.p.pure_pursuit, path, self.vehicle)
        rospy.loginfo("following a path of %.1f m at up to %.1f m/s", path.length, float(path.v.max()))

    def _on_pose(self, m: Odometry) -> None:
        with self.lock:
            self.pose = m

    def _tick(self, _event) -> None:
        with self.lock:
            pp, pose = self.pp, self.pose
            if pp is None or pose is None:
                return
            q = pose.pose.pose.orientation
            th = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
            now = rospy.Time.now()
            age = max(0.0, (now - pose.header.stamp).to_sec())
            c = pp.update(pose.pose.pose.position.x, pose.pose.pose.position.y, th, pose.twist.twist.linear.x, age)
        sp = Setpoint()
        sp.header.stamp = now
        sp.speed, sp.handlebar, sp.brake = c.speed, c.handlebar, c.brake
        self.pub_sp.publish(sp)
        st = FollowerStatus()
        st.header.stamp = now
        st.status, st.cross_track, st.progress = c.status, c.cross_track, c.progress
        st.remaining = c.remaining if math.isfinite(c.remaining) else 0.0
        st.reason = c.reason
        self.pub_status.publish(st)
        if c.status != self.last_status:
            (rospy.logwarn if c.status == ABORTED else rospy.loginfo)(
                "follower %s%s", STATUS_NAMES[c.status], f": {c.reason}" if c.reason else "")
            self.last_status = c.status


def main() -> None:
    rospy.init_node("follower")
    FollowerNode()
    rospy.spin()
