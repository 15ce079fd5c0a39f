"""Reference path publisher: the scenario's path, placed relative to where the vehicle is.

Parameters (private, ``config/path.yaml``; a scenario's ``path:`` section overrides):
``~kind`` (figure_eight | waypoints), ``~figure_eight`` (diameters, lead, laps),
``~waypoints`` ([[x, y], ...] in the vehicle's start frame), ``~ds`` (m),
``~frame_id`` (map).

Subscribes: ``localization/odom`` (the first estimate fixes the start pose).
Publishes: ``planner/path`` (nav_msgs/Path, latched), once.
"""

from __future__ import annotations

import math
import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg

from quadrivio_description.ros.params import fatal, node_params, with_scenario

from ..paths import PathParams, path_points


def to_msg(points: np.ndarray, frame_id: str, stamp: rospy.Time) -> PathMsg:
    msg = PathMsg()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    heading = np.arctan2(np.gradient(points[:, 1]), np.gradient(points[:, 0]))
    for (x, y), th in zip(points, heading):
        ps = PoseStamped()
        ps.header = msg.header
        ps.pose.position.x, ps.pose.position.y = float(x), float(y)
        ps.pose.orientation.z, ps.pose.orientation.w = math.sin(th / 2), math.cos(th / 2)
        msg.poses.append(ps)
    return msg


class PathPublisher:
    def __init__(self) -> None:
        self.p: PathParams = with_scenario(node_params(PathParams), "path")
        self.pub = rospy.Publisher("planner/path", PathMsg, queue_size=1, latch=True)
        self.sub = rospy.Subscriber("localization/odom", Odometry, self._on_odom, queue_size=1)
        rospy.loginfo("path publisher: %s, waiting for the first localization estimate", self.p.kind)

    def _on_odom(self, m: Odometry) -> None:
        self.sub.unregister()
        q = m.pose.pose.orientation
        th = math.atan2(2 * (q.w * q.z + q.x * q.y), 1 - 2 * (q.y * q.y + q.z * q.z))
        start = (m.pose.pose.position.x, m.pose.pose.position.y, th)
        c, s = math.cos(th), math.sin(th)
        waypoints = [(start[0] + c * x - s * y, start[1] + s * x + c * y) for x, y in self.p.waypoints]
        try:
            pts = path_points(self.p.kind, start, self.p.figure_eight, waypoints, self.p.ds)
        except ValueError as exc:
            fatal(f"cannot build the path: {exc}")
        self.pub.publish(to_msg(pts, self.p.frame_id, m.header.stamp))
        length = float(np.sum(np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))))
        rospy.loginfo("published a %s path of %.1f m from (%.2f, %.2f, %.1f deg)", self.p.kind, length, start[0],
                      start[1], math.degrees(th))


def main() -> None:
    rospy.init_node("path_publisher")
    PathPublisher()
    rospy.spin()
