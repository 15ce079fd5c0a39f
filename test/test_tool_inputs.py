"""Every tool that reads a recording turns corrupt input into one clear line and writes
nothing half-done: a damaged compressed chunk, a corrupt run_info.json, bad arguments."""

import pytest
import rosbag
import rospy
from nav_msgs.msg import Odometry
from sensor_msgs.msg import Imu, MagneticField, NavSatFix

from quadrivio.ros import analyze_cli, experiment_cli
from quadrivio_localization.ros import calibrate_mag_cli, replay_cli
from quadrivio_plc.msg import VehicleState
from quadrivio_sim.ros import calibrate_cli


def _recording(path, compression):
    with rosbag.Bag(str(path), "w", compression=compression, chunk_threshold=4096) as bag:
        for k in range(3000):
            t = rospy.Time(1.0 + 0.01 * k)
            imu = Imu()
            imu.header.stamp = t
            imu.linear_acceleration.z = 9.81
            bag.write("/imu/data", imu, t)
            st = VehicleState()
            st.header.stamp, st.wheel_speed = t, 1.0
            bag.write("/vehicle/state", st, t)
            mag = MagneticField()
            mag.header.stamp, mag.magnetic_field.x = t, 2e-5
            bag.write("/imu/mag", mag, t)
            gt = Odometry()
            gt.header.stamp, gt.header.frame_id = t, "map"
            gt.pose.pose.position.x = 0.01 * k
            gt.pose.pose.orientation.w = 1.0
            bag.write("/ground_truth/odom", gt, t)
            if k % 20 == 0:
                fix = NavSatFix()
                fix.header.stamp, fix.latitude, fix.longitude = t, 45.478, 9.2276
                bag.write("/gps/fix", fix, t)


@pytest.fixture(scope="module", params=["lz4", "bz2"])
def corrupt_bag(request, tmp_path_factory):
    """A recording whose third chunk has damaged compressed data (its index is intact)."""
    path = tmp_path_factory.mktemp("bags") / f"damaged_{request.param}.bag"
    _recording(path, request.param)
    with rosbag.Bag(str(path)) as bag:
        pos = sorted(c.pos for c in bag._chunks)[2]
    data = bytearray(path.read_bytes())
    for k in range(pos + 120, pos + 160):  # past the chunk's header, inside its compressed data
        data[k] ^= 0x5A
    path.write_bytes(bytes(data))
    with rosbag.Bag(str(path)) as bag, pytest.raises(Exception):  # what the tools must not show
        for _ in bag.read_messages():
            pass
    return path


def _one_clear_line(err):
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert lines and "Traceback" not in err, err
    return lines[0]


def test_analyze(corrupt_bag, tmp_path, capsys):
    out = tmp_path / "analysis"
    assert analyze_cli.main([str(corrupt_bag), "--out", str(out)]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert str(corrupt_bag) in line and "corrupt data after t = " in line and "rosbag filter" in line
    assert not out.exists()


def test_replay(corrupt_bag, tmp_path, capsys):
    out = tmp_path / "replayed.bag"
    assert replay_cli.main([str(corrupt_bag), "--out", str(out), "--quiet"]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert "corrupt data after t = " in line
    assert not out.exists() and not [p for p in tmp_path.iterdir() if p.name.startswith(".replay")]


def test_calibrate(corrupt_bag, tmp_path, capsys):
    out = tmp_path / "cal"
    args = ["--setpoint-topic", "/vehicle/state", "--measurement-topic", "/vehicle/state", "--stamp", "header"]
    assert calibrate_cli.main([str(corrupt_bag), "--out", str(out)] + args) == 2
    err = capsys.readouterr().err
    assert "corrupt data after t = " in _one_clear_line(err) and not out.exists()


def test_calibrate_mag(corrupt_bag, tmp_path, capsys):
    out = tmp_path / "mag.yaml"
    assert calibrate_mag_cli.main([str(corrupt_bag), "--out", str(out)]) == 2
    assert "corrupt data after t = " in _one_clear_line(capsys.readouterr().err)
    assert not out.exists()


@pytest.mark.parametrize("content", ["{not json", "[1, 2]", ""])
def test_analyze_with_a_corrupt_run_info(tmp_path, capsys, content):
    bag = tmp_path / "run.bag"
    _recording(bag, "none")
    (tmp_path / "run_info.json").write_text(content)
    out = tmp_path / "analysis"
    assert analyze_cli.main([str(bag), "--out", str(out)]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert "run_info.json" in line and "unreadable" in line and not out.exists()


@pytest.mark.parametrize("args,what", [(["--rtf", "-1"], "--rtf -1.0"), (["--rtf", "nan"], "--rtf nan"),
                                       (["--seed", "-3"], "--seed"), (["--wall-timeout", "-5"], "--wall-timeout"),
                                       (["--stale-fraction", "1"], "--stale-fraction"),
                                       (["--stale-fraction", "nan"], "--stale-fraction")])
def test_experiment_checks_its_arguments_before_launching(tmp_path, capsys, args, what):
    out = tmp_path / "run"
    assert experiment_cli.main(["figure_eight", "--out", str(out)] + args) == 2
    assert what in _one_clear_line(capsys.readouterr().err)
    assert not out.exists()  # nothing launched, nothing prepared


def test_analyze_exits_non_zero_on_a_bag_without_any_topic_it_reads(tmp_path, capsys):
    bag = tmp_path / "other_drivers.bag"
    with rosbag.Bag(str(bag), "w") as b:
        for k in range(100):  # another driver's topic: nothing analyze reads without a mapping
            fix = NavSatFix()
            fix.header.stamp = rospy.Time(1.0 + k)
            b.write("/fix", fix, fix.header.stamp)
    out = tmp_path / "out"
    assert analyze_cli.main([str(bag), "--out", str(out)]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert "holds none of the topics the analysis reads" in line and "/gps/fix" in line and "--map" in line
    assert not out.exists() or not (out / "metrics.json").exists()


def _bag_with_field(path, field_x):
    """A short recording whose magnetometer reads ``field_x`` in its message's tesla field."""
    with rosbag.Bag(str(path), "w") as bag:
        for k in range(400):
            t = rospy.Time(1.0 + 0.01 * k)
            imu = Imu()
            imu.header.stamp = t
            imu.linear_acceleration.z = 9.81
            bag.write("/imu/data", imu, t)
            mag = MagneticField()
            mag.header.stamp, mag.magnetic_field.x = t, field_x
            bag.write("/imu/mag", mag, t)
            if k % 20 == 0:
                fix = NavSatFix()
                fix.header.stamp, fix.latitude, fix.longitude = t, 45.478, 9.2276
                fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
                fix.position_covariance = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 4.0]
                bag.write("/gps/fix", fix, t)


@pytest.mark.parametrize("tool", ["replay", "calibrate_mag"])
def test_a_field_in_the_wrong_unit_is_named_not_a_traceback(tmp_path, capsys, tool):
    """The issue's recording: an Xsens field normalised to ~0.9, read as tesla (0.9 T): replay
    died in GTSAM ("Indeterminate linear system") and wrote nothing. Now both tools stop at
    once with the likely unit mistake named, and write nothing."""
    bag = tmp_path / "xsens.bag"
    _bag_with_field(bag, 0.9)
    out = tmp_path / ("replayed.bag" if tool == "replay" else "mag.yaml")
    cli = replay_cli if tool == "replay" else calibrate_mag_cli
    assert cli.main([str(bag), "--out", str(out)] + (["--quiet"] if tool == "replay" else [])) == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err
    assert "reads a field of 9e+05 uT" in err and "normalised to the local Earth field" in err
    assert "nothing written" in err and not out.exists()


def test_every_gps_decision_is_visible_in_the_replayed_bag_the_csv_and_analyze(tmp_path):
    """Which fixes were used, and why not: replay writes one GpsDecision per fix on
    /localization/gps_decisions and, with --gps-csv, a CSV; analyze counts them and marks the
    rejected fixes on trajectory.png. A standing vehicle with fixes at 5 Hz, five of them
    30 m off after the estimate has settled."""
    import csv
    import json

    bag = tmp_path / "standing.bag"
    with rosbag.Bag(str(bag), "w") as b:
        for k in range(6000):  # 60 s at 100 Hz
            t = rospy.Time(1.0 + 0.01 * k)
            imu = Imu()
            imu.header.stamp = t
            imu.linear_acceleration.z = 9.81
            b.write("/imu/data", imu, t)
            if k % 2 == 0:
                st = VehicleState()
                st.header.stamp = t
                b.write("/vehicle/state", st, t)
            if k % 4 == 0:
                mag = MagneticField()
                mag.header.stamp, mag.magnetic_field.x, mag.magnetic_field.z = t, 2.2e-5, -4.0e-5
                b.write("/imu/mag", mag, t)
            if k % 20 == 0:
                fix = NavSatFix()
                off = 30.0 / 111_320.0 if 4000 <= k < 4100 else 0.0  # 5 fixes 30 m north
                fix.header.stamp, fix.latitude, fix.longitude = t, 45.478 + off, 9.2276
                fix.status.status = 0
                fix.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
                fix.position_covariance = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 4.0]
                b.write("/gps/fix", fix, t)
    out, table = tmp_path / "replayed.bag", tmp_path / "gps.csv"
    assert replay_cli.main([str(bag), "--out", str(out), "--gps-csv", str(table), "--quiet"]) == 0
    rows = list(csv.DictReader(open(table)))
    with rosbag.Bag(str(out)) as r:
        decisions = [m for _, m, _ in r.read_messages(topics=["/localization/gps_decisions"])]
    assert len(rows) == len(decisions) >= 290  # one per fix (the last ones may still wait for their group)
    rejected = [row for row in rows if row["used"] == "0"]
    assert 5 <= len(rejected) <= 12 and all(row["reason"] in ("outlier", "multipath") for row in rejected)
    assert all(39.99 < float(row["t"]) < 42.5 for row in rejected)  # the 30 m burst, not the good fixes
    analysis = tmp_path / "analysis"
    assert analyze_cli.main([str(out), "--out", str(analysis)]) == 0
    m = json.loads((analysis / "metrics.json").read_text())
    assert m["gps_fixes_used"] == len(rows) - len(rejected)
    assert sum(v for k, v in m.items() if k.startswith("gps_fixes_rejected_")) == len(rejected)
    assert (analysis / "trajectory.png").exists()


def test_a_long_recording_shows_progress(tmp_path, capsys, monkeypatch):
    """A field recording of hours takes analyze minutes: it says how far it is (by recorded
    time, at most every PROGRESS_S of wall time), then each phase; a short bag says nothing."""
    import re

    from quadrivio.ros.bag import read_run
    from quadrivio_description.site import load_site
    from quadrivio_description.vehicle import load_vehicle

    bag = tmp_path / "field.bag"
    with rosbag.Bag(str(bag), "w") as b:
        for k in range(601):  # 600 s of recording, an estimate a second
            t = rospy.Time(100.0 + k)
            est = Odometry()
            est.header.stamp, est.header.frame_id = t, "map"
            est.pose.pose.position.x = 0.5 * k
            est.pose.pose.orientation.w = 1.0
            b.write("/localization/odom", est, t)
    from quadrivio_recordings import progress

    seen = []
    read_run(str(bag), load_site(), load_vehicle(), progress=seen.append)
    assert [round(t) for t in seen] == list(range(106, 701, 6))  # each hundredth of the 600 s from 100 s

    monkeypatch.setattr(progress, "PROGRESS_S", 0.0)
    assert analyze_cli.main([str(bag), "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    percents = [int(p) for p in re.findall(r"reading field\.bag: +(\d+) % of 600 s recorded", err)]
    assert percents == list(range(1, 101))
    assert "computing the metrics" in err and "drawing the plots" in err
    monkeypatch.setattr(progress, "LONG_BAG_S", 601.0)  # shorter than that: silent
    assert analyze_cli.main([str(bag), "--out", str(tmp_path / "b")]) == 0
    assert "[analyze] reading" not in capsys.readouterr().err


def test_topics_stamped_on_another_clock_are_named(tmp_path, capsys):
    """A driver stamping with GPS time or its device's clock, or not at all: its topic's errors
    against the others would compare different moments. analyze names it; the topics on the
    recorder's clock (a 0.2 s late fix included) pass."""
    from quadrivio.ros.bag import read_run
    from quadrivio_description.site import load_site
    from quadrivio_description.vehicle import load_vehicle

    bag = tmp_path / "clocks.bag"
    with rosbag.Bag(str(bag), "w") as b:
        for k in range(200):
            t = rospy.Time.from_sec(1_700_000_000.0 + 0.1 * k)  # a wall-clock recording
            est = Odometry()
            est.header.stamp, est.header.frame_id = t, "map"
            est.pose.pose.orientation.w = 1.0
            b.write("/localization/odom", est, t)
            fix = NavSatFix()
            fix.header.stamp, fix.latitude, fix.longitude = t - rospy.Duration.from_sec(0.2), 45.478, 9.2276
            b.write("/gps/fix", fix, t)
            st = VehicleState()  # stamped 0: the driver never set it
            b.write("/vehicle/state", st, t)
            gt = Odometry()  # GPS time: 18 leap seconds ahead
            gt.header.stamp, gt.header.frame_id = t + rospy.Duration(18), "map"
            gt.pose.pose.orientation.w = 1.0
            b.write("/ground_truth/odom", gt, t)
    run = read_run(str(bag), load_site(), load_vehicle())
    assert len(run.warnings) == 2
    gt_w, state_w = run.warnings
    assert gt_w.startswith("/ground_truth/odom: its stamps are +18 s off the other topics'") and "another clock" in gt_w
    assert state_w.startswith("/vehicle/state:") and "200 of its first 200 messages are stamped 0" in state_w
    assert analyze_cli.main([str(bag), "--out", str(tmp_path / "a")]) == 0
    err = capsys.readouterr().err
    assert err.count("[analyze] WARNING:") == 2 and "/gps/fix" not in err
    # every topic on one other clock (a device's, 1000 s ahead of the recorder): consistent
    same = tmp_path / "same.bag"
    with rosbag.Bag(str(same), "w") as b:
        for k in range(50):
            t = rospy.Time.from_sec(100.0 + 0.1 * k)
            for topic in ("/localization/odom", "/ground_truth/odom"):
                m = Odometry()
                m.header.stamp = t + rospy.Duration(1000)
                m.pose.pose.orientation.w = 1.0
                b.write(topic, m, t)
    assert read_run(str(same), load_site(), load_vehicle()).warnings == []


def _device_clock_imu(path, n, state_and_fixes=False):
    """``n`` samples at 100 Hz of an IMU stamped on its device's clock (1000 s ahead) and a
    magnetometer on the recorder's, with vehicle states and 5 Hz fixes if asked."""
    with rosbag.Bag(str(path), "w") as b:
        for k in range(n):
            t = rospy.Time(1.0 + 0.01 * k)
            imu = Imu()
            imu.header.stamp = t + rospy.Duration(1000)
            imu.linear_acceleration.z = 9.81
            b.write("/imu/data", imu, t)
            mag = MagneticField()
            mag.header.stamp, mag.magnetic_field.x, mag.magnetic_field.z = t, 2.2e-5, -4.0e-5
            b.write("/imu/mag", mag, t)
            if state_and_fixes:
                st = VehicleState()
                st.header.stamp = t
                b.write("/vehicle/state", st, t)
                if k % 20 == 0:
                    fix = NavSatFix()
                    fix.header.stamp, fix.latitude, fix.longitude = t, 45.478, 9.2276
                    b.write("/gps/fix", fix, t)
    return path


def test_replay_refuses_an_imu_stamped_on_its_own_clock(tmp_path, capsys):
    """The smoother fuses by stamps: an IMU on its device's clock (1000 s ahead of the rest)
    would be fused with fixes and wheel speeds of other moments. replay refuses, naming the
    topic and the mapping key that reads it by its recording time; nothing is written."""
    bag = _device_clock_imu(tmp_path / "device_clock.bag", 600, state_and_fixes=True)
    out = tmp_path / "replayed.bag"
    assert replay_cli.main([str(bag), "--out", str(out), "--quiet"]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert "/imu/data: its stamps are +1000 s off the other topics'" in line and "stamp: receipt" in line
    assert not out.exists()


def test_calibrate_mag_refuses_an_imu_on_another_clock(tmp_path, capsys):
    """The IMU levels the magnetometer at its stamps: on its device's clock (1000 s ahead)
    it would level readings of other moments."""
    bag = _device_clock_imu(tmp_path / "device_clock.bag", 400)
    out = tmp_path / "mag.yaml"
    assert calibrate_mag_cli.main([str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "/imu/data: its stamps are +1000 s off the other topics'" in err and "Traceback" not in err
    assert not out.exists()


def test_calibrate_refuses_a_state_on_another_clock(tmp_path, capsys):
    """A dead time fitted across two clocks would be their offset: the PLC's states stamped on
    its own clock (40 s behind) are refused, with the option that times them by the bag."""
    from quadrivio_plc.msg import Setpoint

    bag = tmp_path / "plc_clock.bag"
    with rosbag.Bag(str(bag), "w") as b:
        for k in range(600):
            t = rospy.Time(100.0 + 0.02 * k)
            sp = Setpoint()
            sp.header.stamp, sp.speed = t, 1.0 if k > 100 else 0.0
            b.write("/vehicle/setpoint/auto", sp, t)
            st = VehicleState()
            st.header.stamp, st.wheel_speed = t - rospy.Duration(40), 1.0 if k > 110 else 0.0
            b.write("/vehicle/state", st, t)
    out = tmp_path / "cal"
    assert calibrate_cli.main([str(bag), "--out", str(out)]) == 2
    line = _one_clear_line(capsys.readouterr().err)
    assert "/vehicle/state: its stamps are -40 s off the other topics'" in line, line
    assert "--stamp bag" in line and not out.exists()


def test_the_map_bodies_the_simulator_built_are_read_back_and_judged_against(tmp_path):
    """/ground_truth/map_bodies (the simulator's node publishes it latched, from the bodies its
    core built from the map) round trip through a bag: read_run gives them, and the run's
    clearance is judged against them rather than against bodies rebuilt with our defaults."""
    from quadrivio.obstacle_metrics import obstacle_metrics
    from quadrivio.ros.bag import read_run
    from quadrivio_description.site import load_site
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.maps import Block
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_sim.ros import converters

    blocks = [Block("cylinder", 4.0, 0.0, 2.0, 2.0, 0.0), Block("box", 0.0, 8.0, 3.0, 1.0, 0.3)]
    msg = converters.map_bodies(blocks, 1.5, "map", 0.0)
    assert [(a.name, a.kind, a.shape, a.height) for a in msg.actors] == \
        [("map_0", "map", "cylinder", 1.5), ("map_1", "map", "box", 1.5)]
    bag = tmp_path / "bodies.bag"
    with rosbag.Bag(str(bag), "w") as b:
        b.write("/ground_truth/map_bodies", msg, rospy.Time.from_sec(0.5))
        for k in range(50):
            t = rospy.Time.from_sec(0.5 + 0.1 * k)
            gt = Odometry()
            gt.header.stamp, gt.header.frame_id = t, "map"
            gt.pose.pose.orientation.w = 1.0
            b.write("/ground_truth/odom", gt, t)
    vehicle = load_vehicle()
    run = read_run(str(bag), load_site(), vehicle)
    assert run.map_bodies == [("map_0", "map", "cylinder", 4.0, 0.0, 0.0, 2.0, 2.0),
                              ("map_1", "map", "box", 0.0, 8.0, 0.3, 3.0, 1.0)]
    front = Footprint.from_vehicle(vehicle).front
    assert obstacle_metrics(run, vehicle)["min_clearance_m"] == pytest.approx(3.0 - front, abs=0.06)
