"""Layer-1 samples to messages (quadrivio_sim.ros.converters): frames from parameters,
conventions of the message types. No master needed."""
import math

import pytest
import rospy

from quadrivio_sim.ros import converters as C
from quadrivio_sim.sensors import ImageSample, ImuSample, MagSample, ScanSample
from quadrivio_sim.simulator import GroundTruth


def test_frames_come_from_the_parameters_not_literals():
    f = C.Frames(map="world", base="chassis", imu="xsens", mag="compass")
    assert C.imu(ImuSample(1.25, (0.0, 0.0, 9.81), (0.0, 0.0, 0.1), (0.0, 0.0, 0.0, 1.0)), f).header.frame_id == "xsens"
    m = C.mag(MagSample(1.25, (2e-5, 0.0, -4e-5)), f)
    assert m.header.frame_id == "compass" and m.header.stamp.to_sec() == pytest.approx(1.25)
    odom, tf = C.ground_truth(GroundTruth(2.0, (1.0, 2.0, 0.3), (0.0, 0.0, 0.0, 1.0), (1.0, 0.0, 0.0),
                                          (0.0, 0.0, 0.0)), f)
    assert (odom.header.frame_id, odom.child_frame_id) == ("world", "chassis")
    assert tf.header.frame_id == "world" and tf.child_frame_id == "base_link_ground_truth"


def test_ground_truth_twist_is_in_the_child_frame():
    yaw = math.pi / 2  # facing north, driving north at 2 m/s, turning at 0.5 rad/s
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    odom, _ = C.ground_truth(GroundTruth(0.0, (0.0, 0.0, 0.0), q, (0.0, 2.0, 0.0), (0.0, 0.0, 0.5)), C.Frames())
    tw = odom.twist.twist
    assert (tw.linear.x, tw.linear.y) == pytest.approx((2.0, 0.0), abs=1e-9)  # forward, in base_link
    assert tw.angular.z == pytest.approx(0.5)


def test_scan_angle_max_is_the_last_beam():
    m = C.scan(ScanSample(0.5, "laser_front", -1.0, 0.5, (1.0, 2.0, float("inf"), 4.0, 5.0), 0.1, 30.0, 0.1))
    assert m.header.frame_id == "laser_front" and m.angle_max == pytest.approx(1.0)
    assert len(m.ranges) == 5 and math.isinf(m.ranges[2])


def test_the_right_camera_carries_the_baseline_in_its_projection():
    s = ImageSample(0.5, "camera_right", 4, 2, bytes(24), 300.0, 300.0, 2.0, 1.0)
    img, info = C.image(s, baseline=0.12, right=True)
    assert img.step == 12 and img.encoding == "rgb8"
    assert info.P[3] == pytest.approx(-300.0 * 0.12)  # Tx = -fx * baseline (REP-104)
    assert C.image(s, baseline=0.12, right=False)[1].P[3] == 0.0


def test_header_stamp_is_read_from_the_serialised_message_of_any_stamped_type():
    from io import BytesIO

    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry

    for msg in (Odometry(), PoseStamped()):
        msg.header.seq = 77
        msg.header.stamp = rospy.Time(12, 345678901)
        msg.header.frame_id = "a_frame_of_another_length"
        buff = BytesIO()
        msg.serialize(buff)
        assert C.header_stamp(buff.getvalue()) == (12, 345678901)
        assert C.starts_with_header(msg._full_text)
    with pytest.raises(ValueError, match="12 bytes"):
        C.header_stamp(b"\x00" * 11)


def test_only_definitions_whose_first_field_is_a_header_count_as_stamped():
    from geometry_msgs.msg import Pose
    from std_msgs.msg import Float64

    assert C.starts_with_header("# a comment first\n\nstd_msgs/Header header  # the stamp\nfloat64 x\n")
    assert not C.starts_with_header(Float64._full_text)
    assert not C.starts_with_header(Pose._full_text)
    assert not C.starts_with_header("float64 x\nHeader header\n")  # a header, but not first: the stamp is elsewhere
    assert not C.starts_with_header("")
