"""calibrate_mag from a bag: a drive in circles with a known distortion is recovered, the
file it writes loads into the localization's parameters; bad input writes nothing."""
import math
import os

import numpy as np
import pytest
import rosbag
import rospy
import yaml
from sensor_msgs.msg import Imu, MagneticField

from quadrivio_config import from_mapping
from quadrivio_description.site import load_site
from quadrivio_localization.ros.calibrate_mag_cli import main
from quadrivio_localization.smoother import LocalizerParams
from quadrivio_plc.msg import VehicleState

S = np.array([[1.05, 0.03, 0.0], [0.03, 0.96, 0.0], [0.0, 0.0, 1.0]])
O = np.array([4.0e-6, -2.5e-6, 1.0e-6])  # [T]


def write_drive(path, seconds=60.0, speed=1.5, radius=5.0, with_state=True, seed=0):
    """Circles at constant speed on flat ground; sensors aligned with base_link (vehicle.yaml)."""
    rng = np.random.default_rng(seed)
    h = np.asarray(load_site().magnetic_field.enu())  # ENU [T]
    w = speed / radius
    with rosbag.Bag(path, "w") as bag:
        for k in range(int(seconds * 50)):
            t = k / 50.0
            stamp = rospy.Time.from_sec(10.0 + t)
            yaw = w * t
            imu = Imu()
            imu.header.stamp = stamp
            imu.linear_acceleration.y = speed * w  # centripetal, to the left
            imu.linear_acceleration.z = 9.81
            imu.angular_velocity.z = w
            bag.write("/imu/data", imu, stamp)
            if k % 2 == 0:
                c, s = math.cos(yaw), math.sin(yaw)
                body = np.array([c * h[0] + s * h[1], -s * h[0] + c * h[1], h[2]])
                m = S @ body + O + rng.normal(0.0, 2e-7, 3)
                mag = MagneticField()
                mag.header.stamp = stamp
                mag.magnetic_field.x, mag.magnetic_field.y, mag.magnetic_field.z = m
                bag.write("/imu/mag", mag, stamp)
            if with_state and k % 2 == 0:
                st = VehicleState()
                st.header.stamp = stamp
                st.wheel_speed = speed
                bag.write("/vehicle/state", st, stamp)


def test_recovers_the_distortion_and_writes_loadable_priors(tmp_path):
    bag = str(tmp_path / "circles.bag")
    write_drive(bag)
    out = tmp_path / "cal" / "mag.yaml"
    assert main([bag, "--out", str(out)]) == 0
    data = yaml.safe_load(out.read_text())
    mag = data["priors"]["magnetometer"]
    assert mag["hard_iron"] == pytest.approx([4.0, -2.5], abs=0.1)
    assert mag["soft_iron"] == pytest.approx([1.05, 0.96, 0.03], abs=0.005)
    assert (tmp_path / "cal" / "mag.png").stat().st_size > 10000
    # What roslaunch loads into the node's namespace: it parses as the smoother's parameters.
    p = from_mapping(LocalizerParams, data, str(out))
    assert p.priors.magnetometer.hard_iron == pytest.approx((4.0, -2.5), abs=0.1)
    assert p.priors.magnetometer.source.startswith("calibrate_mag circles.bag")


def test_half_a_circle_is_refused_and_nothing_is_written(tmp_path, capsys):
    bag = str(tmp_path / "arc.bag")
    write_drive(bag, seconds=9.0)  # 1.5 m/s on 5 m: 155 degrees
    out = tmp_path / "mag.yaml"
    assert main([bag, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "degrees of heading" in err and "full circle" in err and "nothing written" in err
    assert not out.exists() and os.listdir(tmp_path) == ["arc.bag"]


def test_missing_bag_and_topic(tmp_path, capsys):
    assert main([str(tmp_path / "none.bag"), "--out", str(tmp_path / "m.yaml")]) == 2
    assert "file not found" in capsys.readouterr().err
    bag = str(tmp_path / "d.bag")
    write_drive(bag, seconds=2.0)
    assert main([bag, "--out", str(tmp_path / "m.yaml"), "--mag-topic", "/mag"]) == 2
    assert "no magnetometer topic /mag" in capsys.readouterr().err
    (tmp_path / "junk.bag").write_bytes(b"#ROSBAG V2.0\n" + os.urandom(200))
    assert main([str(tmp_path / "junk.bag"), "--out", str(tmp_path / "m.yaml")]) == 2
    assert "bag" in capsys.readouterr().err
    assert not (tmp_path / "m.yaml").exists()
