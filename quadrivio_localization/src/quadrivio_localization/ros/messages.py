"""Conversions between ROS messages and the smoother, shared by the node and ``replay``
so that the offline run sees and says exactly what the online one does."""

from __future__ import annotations

import math

from nav_msgs.msg import Odometry
from sensor_msgs.msg import NavSatFix

from quadrivio_description.frames import quaternion_from_rpy

from ..msg import Calibration, GpsDecision
from ..smoother import CALIBRATION_NAMES, Estimate, Localizer


# ------------------------------------------------------------------ inputs
def add_state(loc: Localizer, m) -> None:
    """quadrivio_plc/VehicleState (or any message with header, wheel_speed, handlebar)."""
    loc.add_vehicle_state(m.header.stamp.to_sec(), m.wheel_speed, m.handlebar)


def add_imu(loc: Localizer, m) -> None:
    a, w = m.linear_acceleration, m.angular_velocity
    loc.add_imu(m.header.stamp.to_sec(), (a.x, a.y, a.z), (w.x, w.y, w.z))


def add_mag(loc: Localizer, m) -> None:
    f = m.magnetic_field
    loc.add_mag(m.header.stamp.to_sec(), (f.x, f.y, f.z))


def add_gps(loc: Localizer, m) -> None:
    cov = m.position_covariance
    known = m.position_covariance_type != NavSatFix.COVARIANCE_TYPE_UNKNOWN
    loc.add_gps(m.header.stamp.to_sec(), m.latitude, m.longitude, m.altitude,
                cov[0] if known else math.nan, cov[4] if known else math.nan, m.status.status)


# ----------------------------------------------------------------- outputs
def odometry(est: Estimate, map_frame: str, base_frame: str) -> Odometry:
    """``localization/odom``: map -> base_link at the keyframe's time, x, y, yaw covariance."""
    import rospy

    m = Odometry()
    m.header.stamp = rospy.Time.from_sec(est.stamp)
    m.header.frame_id, m.child_frame_id = map_frame, base_frame
    p = m.pose.pose
    p.position.x, p.position.y, p.position.z = est.x, est.y, est.z
    p.orientation.x, p.orientation.y, p.orientation.z, p.orientation.w = quaternion_from_rpy(est.roll, est.pitch, est.theta)
    cov = [0.0] * 36
    for i, a in enumerate((0, 1, 5)):  # x, y, yaw
        for j, b in enumerate((0, 1, 5)):
            cov[6 * a + b] = float(est.covariance[i, j])
    cov[14] = cov[21] = cov[28] = 1e3  # z, roll, pitch: not estimated by the smoother
    m.pose.covariance = cov
    m.twist.twist.linear.x = est.speed
    m.twist.twist.angular.z = est.yaw_rate
    return m


def calibration(est: Estimate, sigma: dict) -> Calibration:
    """``localization/calibration``: the self-calibrated parameters and their sigmas (SI)."""
    import rospy

    c = est.calibration
    m = Calibration()
    m.header.stamp = rospy.Time.from_sec(est.stamp)
    m.wheel_speed_scale, m.handlebar_offset = c["wheel_speed_scale"], c["handlebar_offset"]
    m.steering_gain, m.gyro_bias = c["steering_gain"], c["gyro_bias"]
    m.mag_hard_iron = [c["mag_hard_iron_x"] * 1e-6, c["mag_hard_iron_y"] * 1e-6]
    m.mag_soft_iron = [c["mag_soft_iron_xx"], c["mag_soft_iron_yy"], c["mag_soft_iron_xy"]]
    scale = [1, 1, 1, 1, 1e-6, 1e-6, 1, 1, 1]
    m.sigma = [sigma.get(n, math.nan) * k for n, k in zip(CALIBRATION_NAMES, scale)]
    return m


def gps_decision(t: float, used: bool, reason: str, d2: float, frame_id: str = "gps_link") -> GpsDecision:
    """The gate's decision on the fix stamped ``t`` (a non-finite ``t``: stamp 0)."""
    import rospy

    m = GpsDecision()
    m.header.stamp = rospy.Time.from_sec(t) if math.isfinite(t) and t >= 0.0 else rospy.Time(0)
    m.header.frame_id = frame_id
    m.used, m.reason, m.mahalanobis2 = bool(used), reason, float(d2)
    return m

