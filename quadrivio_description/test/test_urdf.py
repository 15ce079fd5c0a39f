"""The URDF is generated from vehicle.yaml, and the committed file is in step with it."""
import math
import os
import xml.etree.ElementTree as ET

import pytest

from quadrivio_description.kinematics import ackermann_wheel_angles
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import REQUIRED_SENSOR_FRAMES, load_vehicle, package_dir


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


@pytest.fixture(scope="module")
def robot(vehicle):
    return ET.fromstring(build_urdf(vehicle))


def test_committed_urdf_is_up_to_date(vehicle):
    with open(os.path.join(package_dir(), "urdf", "quadrivio.urdf")) as fh:
        committed = fh.read()
    assert committed == build_urdf(vehicle), (
        "urdf/quadrivio.urdf differs from config/vehicle.yaml: run "
        "'rosrun quadrivio_description generate_urdf --out quadrivio_description/urdf/quadrivio.urdf'")


def test_total_mass(robot, vehicle):
    masses = [float(m.get("value")) for m in robot.iter("mass")]
    sensors = 0.01 * len(vehicle.sensors)
    assert sum(masses) == pytest.approx(vehicle.body.mass + sensors)


def test_joints(robot, vehicle):
    joints = {j.get("name"): j for j in robot.iter("joint")}
    for corner in ("front_left", "front_right", "rear_left", "rear_right"):
        s = joints[f"{corner}_suspension_joint"]
        assert s.get("type") == "prismatic"
        axle = vehicle.suspension.front if corner.startswith("front") else vehicle.suspension.rear
        assert float(s.find("limit").get("lower")) == pytest.approx(-axle.travel_down)
        assert float(s.find("limit").get("upper")) == pytest.approx(axle.travel_up)
        assert joints[f"{corner}_wheel_joint"].get("type") == "continuous"
        x, y, _ = map(float, s.find("origin").get("xyz").split())
        assert x == pytest.approx(vehicle.wheelbase if corner.startswith("front") else 0.0)
        track = vehicle.front_track if corner.startswith("front") else vehicle.rear_track
        assert abs(y) == pytest.approx(track / 2)
    lock, _ = ackermann_wheel_angles(vehicle.max_wheel_angle, vehicle.wheelbase, vehicle.front_track)
    for side in ("front_left", "front_right"):
        lim = joints[f"{side}_steer_joint"].find("limit")
        assert float(lim.get("upper")) == pytest.approx(lock, abs=1e-5)
        assert lock > vehicle.max_wheel_angle  # the inner wheel turns more than the virtual wheel


def test_sensor_frames(robot, vehicle):
    links = {link.get("name") for link in robot.iter("link")}
    for frame in REQUIRED_SENSOR_FRAMES:
        assert frame in links
    joints = {j.get("name"): j for j in robot.iter("joint")}
    gps = joints["gps_link_joint"].find("origin").get("xyz").split()
    assert tuple(map(float, gps)) == pytest.approx(vehicle.sensors["gps_link"].xyz)
    cam = joints["camera_left_joint"].find("origin").get("rpy").split()
    assert float(cam[0]) == pytest.approx(-math.pi / 2)


def test_root_inertia_option(vehicle):
    full = ET.fromstring(build_urdf(vehicle))
    kdl = ET.fromstring(build_urdf(vehicle, root_inertia=False))
    base = [link for link in kdl.iter("link") if link.get("name") == "base_link"][0]
    assert base.find("inertial") is None
    assert len(list(full.iter("inertial"))) == len(list(kdl.iter("inertial"))) + 1
