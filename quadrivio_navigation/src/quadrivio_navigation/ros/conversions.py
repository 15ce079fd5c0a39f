"""Message conversions shared by the navigation nodes: poses and paths."""

from __future__ import annotations

from typing import Sequence

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Path as PathMsg

from quadrivio_description.frames import quaternion_from_yaw, yaw_from_quaternion


def yaw_of(q) -> float:
    """Yaw [rad] of a geometry_msgs/Quaternion."""
    return yaw_from_quaternion(q.x, q.y, q.z, q.w)


def pose_stamped(x: float, y: float, yaw: float, frame_id: str, stamp: rospy.Time) -> PoseStamped:
    ps = PoseStamped()
    ps.header.stamp, ps.header.frame_id = stamp, frame_id
    ps.pose.position.x, ps.pose.position.y = float(x), float(y)
    q = quaternion_from_yaw(float(yaw))
    ps.pose.orientation.x, ps.pose.orientation.y, ps.pose.orientation.z, ps.pose.orientation.w = q
    return ps


def path_msg(poses: Sequence[Sequence[float]], frame_id: str, stamp: rospy.Time) -> PathMsg:
    """A nav_msgs/Path of poses (x, y, yaw): each orientation is the vehicle's heading, so
    a step that points against it is driven in reverse."""
    msg = PathMsg()
    msg.header.stamp, msg.header.frame_id = stamp, frame_id
    msg.poses = [pose_stamped(x, y, th, frame_id, stamp) for x, y, th in np.asarray(poses, float)[:, :3]]
    return msg
