"""Import mappings: a recording in other drivers' types and units replays, through its
mapping, to the same estimate as its converted twin; bad mappings are refused in one line."""
import math
import os

import numpy as np
import pytest
import yaml

from quadrivio_config import ConfigError
from quadrivio_recordings.ros import import_map

# The foreign recording's conventions: gyro in deg/s, accelerometer in g, magnetometer in
# gauss, the IMU mounted with y and z reversed, positions in NED about another origin, and
# the PLC's raw units for wheel speed (mm/s) and handlebar (1e-4 rad, left negative).
G = 9.80665
DEG = math.pi / 180.0
SPEED_SCALE, STEER_SCALE = 0.001, -1.0e-4


def flip(v):
    return (v[0], -v[1], -v[2])


@pytest.fixture(scope="module")
def twins(tmp_path_factory):
    import rosbag
    import rospy
    from geometry_msgs.msg import PoseStamped, Vector3Stamped
    from sensor_msgs.msg import Imu, MagneticField, NavSatFix

    from quadrivio import offline
    from quadrivio.scenario import load_scenario
    from quadrivio_description.site import Datum, SiteParams, load_site
    from quadrivio_plc.msg import VehicleState

    d = tmp_path_factory.mktemp("import")
    src = load_scenario("rtk")
    data = dict(src.data)
    data["run"] = {"max_duration": 40.0, "end": "duration"}
    scen = d / "short.yaml"
    scen.write_text(yaml.safe_dump(data))
    r = offline.run(load_scenario(str(scen)), 3)
    site = load_site()
    origin = (site.datum.latitude + 0.001, site.datum.longitude - 0.002, site.datum.altitude + 5.0)
    other = SiteParams(Datum(*origin), site.magnetic_field, site.utc_epoch).local_frame()
    std = math.sqrt(r.inputs.gps[0][5])
    ours, foreign = str(d / "ours.bag"), str(d / "foreign.bag")
    with rosbag.Bag(ours, "w") as a, rosbag.Bag(foreign, "w") as b:
        rows = [(x[0], "state", x) for x in r.inputs.state] + [(x[0], "imu", x) for x in r.inputs.imu] + \
            [(x[0], "mag", x) for x in r.inputs.mag] + [(x[0], "gps", x) for x in r.inputs.gps if x[7] >= 0]
        rows.sort(key=lambda e: e[0])
        for deliver, kind, x in rows:
            at, stamp = rospy.Time.from_sec(deliver), rospy.Time.from_sec(x[1])
            if kind == "state":
                m = VehicleState()
                m.header.stamp, m.wheel_speed, m.handlebar = stamp, x[2], x[3]
                a.write("/vehicle/state", m, at)
                f = Vector3Stamped()
                f.header.stamp = stamp
                f.vector.x, f.vector.y = x[2] / SPEED_SCALE, x[3] / STEER_SCALE
                b.write("/plc/status", f, at)
            elif kind == "imu":
                m = Imu()
                m.header.stamp = stamp
                m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = x[2:5]
                m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = x[5:8]
                a.write("/imu/data", m, at)
                f = Imu()
                f.header.stamp = stamp
                f.linear_acceleration.x, f.linear_acceleration.y, f.linear_acceleration.z = \
                    (v / G for v in flip(x[2:5]))
                f.angular_velocity.x, f.angular_velocity.y, f.angular_velocity.z = (v / DEG for v in flip(x[5:8]))
                b.write("/xsens/imu", f, at)
            elif kind == "mag":
                m = MagneticField()
                m.header.stamp = stamp
                m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = x[2:5]
                a.write("/imu/mag", m, at)
                f = Vector3Stamped()
                f.header.stamp = stamp
                f.vector.x, f.vector.y, f.vector.z = (v * 1e4 for v in flip(x[2:5]))
                b.write("/xsens/mag", f, at)
            else:
                m = NavSatFix()
                m.header.stamp = stamp
                m.latitude, m.longitude, m.altitude = x[2:5]
                m.position_covariance = [std ** 2, 0, 0, 0, std ** 2, 0, 0, 0, 4 * std ** 2]
                m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
                m.status.status = 2
                a.write("/gps/fix", m, at)
                e, n, u = other.lla_to_enu(*x[2:5])
                f = PoseStamped()
                f.header.stamp = stamp
                f.pose.position.x, f.pose.position.y, f.pose.position.z = n, e, -u
                b.write("/ublox/pose", f, at)
    mapping = {
        "gps": {"topic": "/ublox/pose", "kind": "position", "field": "pose.position", "frame": "ned",
                "origin": list(origin), "std": std, "status": "GBAS_FIX"},
        "imu": {"topic": "/xsens/imu", "accel_scale": G, "gyro_scale": DEG, "axes": ["x", "-y", "-z"]},
        "mag": {"topic": "/xsens/mag", "field": "vector", "unit": "gauss", "axes": ["x", "-y", "-z"]},
        "state": {"topic": "/plc/status", "wheel_speed": {"field": "vector.x", "scale": SPEED_SCALE},
                  "handlebar": {"field": "vector.y", "scale": STEER_SCALE}},
    }
    mfile = d / "foreign_map.yaml"
    mfile.write_text(yaml.safe_dump(mapping))
    return d, ours, foreign, str(mfile), mapping


def odom(path):
    import rosbag

    with rosbag.Bag(path) as bag:
        return np.array([(m.header.stamp.to_sec(), m.pose.pose.position.x, m.pose.pose.position.y)
                         for _, m, _ in bag.read_messages(topics=["/localization/odom"])])


def replay(args):
    from quadrivio_localization.ros import replay_cli

    return replay_cli.main(args + ["--quiet", "--only-outputs"])


def test_foreign_bag_replays_like_its_converted_twin(twins):
    d, ours, foreign, mfile, _ = twins
    assert replay([ours, "--out", str(d / "a.bag")]) == 0
    assert replay([foreign, "--map", mfile, "--out", str(d / "b.bag")]) == 0
    a, b = odom(str(d / "a.bag")), odom(str(d / "b.bag"))
    assert len(a) > 500 and a.shape == b.shape
    assert np.abs(a - b).max() < 1e-6, np.abs(a - b).max()


def test_without_the_mapping_the_foreign_bag_is_refused(twins, capsys):
    d, _, foreign, _, _ = twins
    assert replay([foreign, "--out", str(d / "c.bag")]) == 2
    err = capsys.readouterr().err
    assert "has no gps topic /gps/fix" in err and "/ublox/pose" in err
    assert not os.path.exists(d / "c.bag")


@pytest.mark.parametrize("change,message", [
    ({"mag": {"unit": "oersted"}}, "mag.unit = 'oersted' is not a unit it knows"),
    ({"imu": {"axes": ["x", "y", "y"]}}, "must use each of x, y, z once"),
    ({"gps": {"std": None}}, "must be a finite number"),
    ({"state": {"wheel_speed": {"field": "vector.x", "gain": 2}}}, "{field: NAME, scale: S, offset: O}"),
    ({"gps": {"stamp": "gps_time"}}, "header, receipt or auto"),
    ({"odometry": {"topic": "/odom"}}, "unknown section(s) odometry"),
])
def test_bad_mappings_are_named(tmp_path, twins, change, message):
    mapping = yaml.safe_load(yaml.safe_dump(twins[4]))
    for section, keys in change.items():
        mapping.setdefault(section, {}).update(keys)
    path = tmp_path / "bad.yaml"
    path.write_text(yaml.safe_dump(mapping))
    with pytest.raises(ConfigError) as e:
        import_map.load(str(path))
    assert message in str(e.value) and str(path) in str(e.value)
    assert "\n" not in str(e.value)


def test_a_missing_topic_or_field_is_named_and_nothing_written(tmp_path, twins, capsys):
    d, _, foreign, _, mapping = twins
    for change, message in (({"gps": {"topic": "/nothere"}}, "has no gps topic /nothere"),
                            ({"gps": {"field": "pose.point"}}, "no field 'pose.point'")):
        m = yaml.safe_load(yaml.safe_dump(mapping))
        for section, keys in change.items():
            m[section].update(keys)
        path = tmp_path / "m.yaml"
        path.write_text(yaml.safe_dump(m))
        out = tmp_path / "out.bag"
        assert replay([foreign, "--map", str(path), "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert not out.exists() and not [f for f in os.listdir(tmp_path) if f.startswith(".replay")]


def test_calibrate_mag_reads_the_foreign_bag_through_the_mapping(twins):
    """The same levelled readings from both bags (the fit itself needs a full circle each
    way, which a 40 s drive is not: compare what is read)."""
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_localization.ros.calibrate_mag_cli import read_levelled

    _, ours, foreign, mfile, _ = twins
    v = load_vehicle()
    a, ca = read_levelled(ours, "/imu/mag", "/imu/data", "/vehicle/state", v, 1.0, 0.3, 0.1)
    b, cb = read_levelled(foreign, "", "", "", v, 1.0, 0.3, 0.1, import_map.load(mfile))
    assert len(a) > 100 and a.shape == b.shape and np.abs(a - b).max() < 1e-6
    assert ca["mag"] == cb["mag"] and ca["state"] == cb["state"]


def test_analyze_reads_the_foreign_bag_and_names_what_it_lacks(twins, capsys):
    """A plain recording (no ground truth, no follower): analyze says which topics it lacks,
    keys that do not apply are null, and through the mapping the GPS and wheel data count."""
    import json

    from quadrivio.ros import analyze_cli

    d, _, foreign, mfile, _ = twins
    out = d / "analysis"
    assert analyze_cli.main([foreign, "--out", str(out), "--map", mfile]) == 0
    text = capsys.readouterr().out
    assert "lacks" in text and "/ground_truth/odom" in text and "/follower/status" in text
    assert "/ublox/pose" not in text.split("lacks")[1]  # mapped: present
    m = json.load(open(out / "metrics.json"))
    assert m["completed"] is None and m["loc_rmse_m"] is None
    assert m["gps_fix_fraction"] is not None and m["gps_fix_fraction"] > 0.9
    assert (out / "trajectory.png").exists() and (out / "control.png").exists()


def test_a_wheel_speed_unit_mistake_is_named_from_the_fixes(tmp_path, twins, capsys):
    """The mapping's wheel speed scale taken for m/s where the raw unit was km/h-like (3.6x):
    the replay names it against the speed the fixes show; the right scale says nothing."""
    d, _, foreign, mfile, mapping = twins
    assert replay([foreign, "--map", mfile, "--out", str(tmp_path / "ok.bag")]) == 0
    assert "wheel speed" not in capsys.readouterr().err
    m = yaml.safe_load(yaml.safe_dump(mapping))
    m["state"]["wheel_speed"]["scale"] = SPEED_SCALE * 3.6
    path = tmp_path / "kmh.yaml"
    path.write_text(yaml.safe_dump(m))
    assert replay([foreign, "--map", str(path), "--out", str(tmp_path / "kmh.bag")]) == 0
    err = capsys.readouterr().err
    assert "the wheel speed is 3.6" in err and "km/h taken for m/s" in err, err
