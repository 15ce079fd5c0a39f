"""Layer-1 samples to ROS messages: one pure converter per kind of sample, frame ids from
the node's parameters (:class:`Frames`), no rospy state. The simulator node publishes
what these return; tests call them on samples without a master."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import List, Tuple

import rospy
from geometry_msgs.msg import TransformStamped
from nav_msgs.msg import Odometry
from sensor_msgs.msg import CameraInfo, Image, Imu, JointState, LaserScan, MagneticField

from quadrivio_sim.msg import RawGps

from ..sensors import GpsSample, ImageSample, ImuSample, MagSample, ScanSample
from ..simulator import GroundTruth, JointSample
from ..world import quat_to_rows, rotate_inverse


@dataclass(frozen=True)
class Frames:
    map: str = "map"
    base: str = "base_link"
    ground_truth_child: str = "base_link_ground_truth"  # the child of map in the ground-truth TF
    imu: str = "imu_link"
    mag: str = "mag_link"


def stamp(t: float) -> rospy.Time:
    return rospy.Time.from_sec(t)


def starts_with_header(definition: str) -> bool:
    """Whether a message definition (a connection header's ``message_definition``) has a
    std_msgs/Header as its first field, so that :func:`header_stamp` reads its stamp."""
    for line in definition.splitlines():
        line = line.split("#", 1)[0].split()
        if line:
            return line[0] in ("Header", "std_msgs/Header")
    return False


def header_stamp(buff: bytes) -> Tuple[int, int]:
    """``(secs, nsecs)`` of a serialised message whose first field is a std_msgs/Header
    (uint32 seq, then the stamp's two uint32, little-endian), without deserialising it."""
    if len(buff) < 12:
        raise ValueError(f"a stamped message has at least 12 bytes, this one {len(buff)}")
    return struct.unpack_from("<II", buff, 4)


def ground_truth(s: GroundTruth, f: Frames) -> Tuple[Odometry, TransformStamped]:
    """``ground_truth/odom`` (twist in the child frame, as nav_msgs/Odometry says) and its TF."""
    m = Odometry()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = f.map
    m.child_frame_id = f.base
    p, q = m.pose.pose.position, m.pose.pose.orientation
    p.x, p.y, p.z = s.position
    q.x, q.y, q.z, q.w = s.orientation
    R = quat_to_rows(s.orientation)
    v = rotate_inverse(R, s.linear_velocity)
    w = rotate_inverse(R, s.angular_velocity)
    tw = m.twist.twist
    tw.linear.x, tw.linear.y, tw.linear.z = v
    tw.angular.x, tw.angular.y, tw.angular.z = w
    t = TransformStamped()
    t.header = m.header
    t.child_frame_id = f.ground_truth_child
    t.transform.translation.x, t.transform.translation.y, t.transform.translation.z = s.position
    t.transform.rotation = m.pose.pose.orientation
    return m, t


def imu(s: ImuSample, f: Frames) -> Imu:
    m = Imu()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = f.imu
    m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = s.orientation
    m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = s.angular_rate
    a = m.linear_acceleration
    a.x, a.y, a.z = s.specific_force
    return m


def gps(s: GpsSample, f: Frames) -> RawGps:
    m = RawGps()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = f.map
    m.position.x, m.position.y, m.position.z = s.position
    m.velocity.x, m.velocity.y, m.velocity.z = s.velocity
    return m


def mag(s: MagSample, f: Frames) -> MagneticField:
    m = MagneticField()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = f.mag
    m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = s.field
    return m


def scan(s: ScanSample) -> LaserScan:
    """In the scanner's own frame (the sample names it: one simulator, several scanners)."""
    m = LaserScan()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = s.frame
    m.angle_min = s.angle_min
    m.angle_increment = s.angle_increment
    m.angle_max = s.angle_min + s.angle_increment * (len(s.ranges) - 1)
    m.scan_time = s.scan_time
    m.range_min, m.range_max = s.range_min, s.range_max
    m.ranges = s.ranges
    return m


def joints(s: JointSample) -> JointState:
    m = JointState()
    m.header.stamp = stamp(s.stamp)
    m.name, m.position, m.velocity = list(s.names), list(s.positions), list(s.velocities)
    return m


def image(s: ImageSample, baseline: float, right: bool) -> Tuple[Image, CameraInfo]:
    """The image and its CameraInfo; ``right``: the second camera of the pair, whose
    projection carries ``Tx = -fx * baseline`` (REP-104)."""
    m = Image()
    m.header.stamp = stamp(s.stamp)
    m.header.frame_id = s.frame
    m.height, m.width, m.encoding, m.step = s.height, s.width, "rgb8", 3 * s.width
    m.data = s.rgb
    info = CameraInfo()
    info.header = m.header
    info.height, info.width, info.distortion_model = s.height, s.width, "plumb_bob"
    info.D = [0.0] * 5
    info.K = [s.fx, 0.0, s.cx, 0.0, s.fy, s.cy, 0.0, 0.0, 1.0]
    info.R = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    tx = -s.fx * baseline if right else 0.0
    info.P = [s.fx, 0.0, s.cx, tx, 0.0, s.fy, s.cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return m, info


__all__: List[str] = ["Frames", "ground_truth", "imu", "gps", "mag", "scan", "joints", "image", "stamp"]


def actors(samples, map_frame: str, t: float):
    """``ground_truth/actors`` (quadrivio_sim/ActorArray) from :class:`ActorSample` s."""
    from quadrivio_sim.msg import Actor, ActorArray

    m = ActorArray()
    m.header.stamp = stamp(t)
    m.header.frame_id = map_frame
    for a in samples:
        out = Actor()
        out.name, out.kind, out.shape = a.name, a.kind, a.shape
        out.pose.x, out.pose.y, out.pose.theta = a.x, a.y, a.yaw
        out.length, out.width, out.height = a.size
        out.speed = a.speed
        m.actors.append(out)
    return m


def map_bodies(blocks, height: float, map_frame: str, t: float):
    """``ground_truth/map_bodies`` (quadrivio_sim/ActorArray, kind ``map``): the bodies the
    simulator built from the map's occupied cells (:class:`quadrivio_navigation.maps.Block` s)."""
    from quadrivio_sim.msg import Actor, ActorArray

    m = ActorArray()
    m.header.stamp = stamp(t)
    m.header.frame_id = map_frame
    for i, b in enumerate(blocks):
        out = Actor()
        out.name, out.kind, out.shape = f"map_{i}", "map", b.kind
        out.pose.x, out.pose.y, out.pose.theta = b.x, b.y, b.yaw
        out.length, out.width, out.height = b.size_x, b.size_y, height
        m.actors.append(out)
    return m


def contact(e, map_frame: str):
    """``ground_truth/contacts`` (quadrivio_sim/Contact) from a :class:`ContactEvent`."""
    from quadrivio_sim.msg import Contact

    m = Contact()
    m.header.stamp = stamp(e.stamp)
    m.header.frame_id = map_frame
    m.body, m.kind, m.speed = e.body, e.kind, e.speed
    m.position.x, m.position.y = e.position
    return m
