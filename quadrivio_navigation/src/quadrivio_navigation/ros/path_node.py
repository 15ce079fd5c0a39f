"""Reference path publisher: the scenario's path, placed relative to where the vehicle is,
or the scenario's goal for the planner.

Parameters (private, ``config/path.yaml``; a scenario's ``path:`` section overrides):
``~kind`` (figure_eight | waypoints | goal), ``~figure_eight`` (diameters, lead, laps),
``~waypoints`` ([[x, y], ...] in the vehicle's start frame), ``~goal`` ([x, y, yaw] in
the map frame), ``~ds`` (m), ``~frame_id`` (map).

Subscribes: ``localization/odom`` (the first estimate fixes the start pose).
Publishes, once: ``planner/path`` (nav_msgs/Path, latched) for a reference path, or
``move_base_simple/goal`` (geometry_msgs/PoseStamped, latched) for kind ``goal``: the
planner node then plans from the vehicle to it, as after rviz's 2D Nav Goal.
"""

from __future__ import annotations

import math
import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg

from quadrivio_runtime.ros import init_node
from quadrivio_runtime.ros.params import fatal, node_params, with_scenario

from ..paths import PathParams, path_points
from .conversions import path_msg, pose_stamped, yaw_of


def to_msg(points: np.ndarray, frame_id: str, stamp: rospy.Time) -> PathMsg:
    """A forward path through ``points``: each pose heads along the path."""
    heading = np.arctan2(np.gradient(points[:, 1]), np.gradient(points[:, 0]))
    return path_msg(np.column_stack([points, heading]), frame_id, stamp)


class PathPublisher:
    def __init__(self) -> None:
        self.p: PathParams = with_scenario(node_params(PathParams), "path")
        self.failed = False
        if self.p.kind == "waypoints" and not self.p.waypoints:
            fatal("bad parameter: path kind 'waypoints' needs at least one waypoint")
        if self.p.kind == "goal":
            self.pub = rospy.Publisher("move_base_simple/goal", PoseStamped, queue_size=1, latch=True)
        else:
            self.pub = rospy.Publisher("planner/path", PathMsg, queue_size=1, latch=True)
        self.sub = rospy.Subscriber("localization/odom", Odometry, self._on_odom, queue_size=1)
        rospy.loginfo("path publisher: %s, waiting for the first localization estimate", self.p.kind)

    def _on_odom(self, m: Odometry) -> None:
        p, q = m.pose.pose.position, m.pose.pose.orientation
        if not all(map(math.isfinite, (p.x, p.y, q.x, q.y, q.z, q.w))):
            rospy.logwarn_throttle(5.0, "path publisher: ignored a localization estimate that is not finite")
            return
        self.sub.unregister()
        if self.p.kind == "goal":
            x, y, yaw = self.p.goal
            self.pub.publish(pose_stamped(x, y, yaw, self.p.frame_id, m.header.stamp))
            rospy.loginfo("sent the goal (%.2f, %.2f, %.1f deg) to the planner", x, y, math.degrees(yaw))
            return
        th = yaw_of(m.pose.pose.orientation)
        start = (m.pose.pose.position.x, m.pose.pose.position.y, th)
        c, s = math.cos(th), math.sin(th)
        waypoints = [(start[0] + c * x - s * y, start[1] + s * x + c * y) for x, y in self.p.waypoints]
        try:
            pts = path_points(self.p.kind, start, self.p.figure_eight, waypoints, self.p.ds)
        except ValueError as exc:  # a callback cannot stop the node by raising: ask for shutdown
            rospy.logfatal("cannot build the path: %s", exc)
            self.failed = True
            rospy.signal_shutdown(f"cannot build the path: {exc}")
            return
        self.pub.publish(to_msg(pts, self.p.frame_id, m.header.stamp))
        length = float(np.sum(np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))))
        rospy.loginfo("published a %s path of %.1f m from (%.2f, %.2f, %.1f deg)", self.p.kind, length, start[0],
                      start[1], math.degrees(th))


def main() -> None:
    init_node("path_publisher")  # joins lockstep when sim.launch lockstep:=true
    node = PathPublisher()
    rospy.spin()
    if node.failed:  # exit status 1, as fatal() gives outside a callback (required nodes end the launch)
        raise SystemExit(1)
