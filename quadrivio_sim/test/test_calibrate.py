"""Actuator calibration: a recording made by a known loop model plus noise is recovered
(parameters within 10 %, response RMS within 1.2x the noise), from a bag whose message
type only the bag itself defines; bad input gets a clear message and writes nothing."""
import json
import os

import genpy
import genpy.dynamic
import numpy as np
import pytest
import rosbag
import rospy
import yaml

from quadrivio_config import replace_nested
from quadrivio_description.vehicle import load_vehicle
from quadrivio_sim.actuators import load_actuators
from quadrivio_sim.calibration import Series, simulate_handlebar, simulate_speed
from quadrivio_sim.paths import package_file
from quadrivio_sim.ros.calibrate_cli import main

# A message type of "another stack", known only through the bag's definitions.
ACTUATION = genpy.dynamic.generate_dynamic(
    "other_stack/Actuation", "Header header\nfloat64 speed\nfloat64 steer\nfloat64 brake\n"
    "\n================================================================================\n"
    "MSG: std_msgs/Header\nuint32 seq\ntime stamp\nstring frame_id\n")["other_stack/Actuation"]

TRUE_HANDLEBAR = {"pid": {"kp": 3.5, "ki": 0.0}, "servo_tau": 0.08, "max_rate": 0.7, "dead_time": 0.06, "max_angle": 0.5}
TRUE_SPEED = {"max_accel": 1.2, "max_decel": 2.5, "engine_brake": 9.0, "dead_time": 0.08}
NOISE_H, NOISE_V = 0.003, 0.02
DT = 0.01


def excitation(T=60.0):
    t = np.arange(0.0, T, DT)
    h = [0.0, 0.05, -0.05, 0.3, -0.3, 0.1, 0.6, -0.6, 0.0, 0.2, -0.15, 0.4, 0.0, 0.03, -0.25, 0.0, 0.15, -0.45,
         0.08, 0.0, 0.35, -0.1, 0.0, 0.5]
    v = [0.0, 2.0, 3.0, 2.7, 2.4, 2.2, 4.0, 1.0, 0.0, 3.0, 2.6, 0.5, 2.0, 0.0]
    hs = np.repeat(h, len(t) // len(h) + 1)[:len(t)]
    vs = np.repeat(v, len(t) // len(v) + 1)[:len(t)]
    return t, hs, vs


def write_bag(path, t, sp_h, sp_v, meas_h, meas_v, topics=("/ctrl/command", "/ctrl/feedback")):
    with rosbag.Bag(path, "w") as bag:
        for k in range(len(t)):
            stamp = rospy.Time.from_sec(100.0 + t[k])
            if k % 2 == 0:  # setpoints at 50 Hz
                m = ACTUATION()
                m.header.stamp = stamp
                m.speed, m.steer, m.brake = sp_v[k], sp_h[k], 0.0
                bag.write(topics[0], m, stamp)
            f = ACTUATION()
            f.header.stamp = stamp
            f.speed, f.steer = meas_v[k], meas_h[k]
            bag.write(topics[1], f, stamp)


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    """A vehicle whose loops are the known model, measured with noise."""
    v = load_vehicle()
    base = load_actuators(package_file("config", "actuators.yaml"))
    t, sp_h, sp_v = excitation()
    rng = np.random.default_rng(5)
    s = Series(t, sp_h, np.zeros_like(t), np.zeros_like(t))
    meas_h = simulate_handlebar(replace_nested(base.handlebar, TRUE_HANDLEBAR), v, s) + rng.normal(0, NOISE_H, len(t))
    s = Series(t, sp_v, np.zeros_like(t), np.zeros_like(t))
    meas_v = simulate_speed(replace_nested(base.speed, TRUE_SPEED), v, 0.03, s) + rng.normal(0, NOISE_V, len(t))
    path = str(tmp_path_factory.mktemp("bags") / "other_stack.bag")
    write_bag(path, t, sp_h, sp_v, meas_h, meas_v)
    return path, t, sp_h, sp_v, meas_h, meas_v


ARGS = ["--setpoint-topic", "/ctrl/command", "--measurement-topic", "/ctrl/feedback",
        "--setpoint-fields", "speed=speed,handlebar=steer,brake=brake", "--measurement-fields", "speed=speed,handlebar=steer,brake="]


def test_identification_recovers_the_model(recording, tmp_path):
    out = tmp_path / "cal"
    assert main([recording[0], "--out", str(out)] + ARGS) == 0
    report = json.loads((out / "calibration.json").read_text())
    h, s = report["loops"]["handlebar"], report["loops"]["speed"]
    for key, true in (("pid.kp", 3.5), ("servo_tau", 0.08), ("max_rate", 0.7), ("dead_time", 0.06), ("max_angle", 0.5)):
        assert h["identified"][key] == pytest.approx(true, rel=0.10), key
    for key, true in TRUE_SPEED.items():
        assert s["identified"][key] == pytest.approx(true, rel=0.10), key
    assert h["fit_rms"] <= 1.2 * NOISE_H
    assert s["fit_rms"] <= 1.2 * NOISE_V
    assert "second-order" in h["notes"][0]
    # The simulator loads what was written, and its references are the recorded vehicle's.
    written = load_actuators(str(out / "actuators.yaml"))
    assert written.handlebar.max_rate == pytest.approx(0.7, rel=0.1)
    assert written.speed.max_decel == pytest.approx(2.5, rel=0.1)
    assert written.speed_reference.step >= 0.5
    for png in ("handlebar.png", "speed.png"):
        assert (out / png).stat().st_size > 10_000
    # Replay through the full PyBullet simulator: the identified handlebar loop is the
    # simulator's own, so the replay matches to the noise; the speed loop drives the
    # full vehicle (tyres, suspension) instead of the point mass, so a looser bound.
    assert h["replay_rms"] <= 1.5 * NOISE_H
    assert s["replay_rms"] <= 0.15


def test_replay_mode_compares_without_fitting(recording, tmp_path):
    out = tmp_path / "replay"
    assert main([recording[0], "--out", str(out), "--replay"] + ARGS) == 0
    report = json.loads((out / "calibration.json").read_text())
    assert report["mode"] == "replay" and not (out / "actuators.yaml").exists()
    assert "identified" not in report["loops"]["handlebar"]
    assert report["loops"]["handlebar"]["replay_rms"] > 0.0
    assert report["loops"]["speed"]["measured"]["rise_time"] > 0.0


def test_missing_topic_is_named_and_nothing_is_written(recording, tmp_path, capsys):
    out = tmp_path / "none"
    assert main([recording[0], "--out", str(out)]) == 2  # default topics are not in this bag
    err = capsys.readouterr().err
    assert "no setpoint topic /vehicle/setpoint/auto" in err and "/ctrl/command (other_stack/Actuation)" in err
    assert "nothing written" in err and not out.exists()


def test_missing_field_is_named(recording, tmp_path, capsys):
    args = [a.replace("handlebar=steer", "handlebar=steering") for a in ARGS]
    assert main([recording[0], "--out", str(tmp_path / "x")] + args) == 2
    assert "has no field 'steering'" in capsys.readouterr().err


def test_too_little_excitation(tmp_path, capsys):
    t = np.arange(0.0, 30.0, DT)
    flat_h = np.where(t > 5, 0.2, 0.0)  # one handlebar step only: no small steps, no rate limit
    flat_v = np.where(t > 5, 1.0, 0.0)
    path = str(tmp_path / "poor.bag")
    rng = np.random.default_rng(1)
    write_bag(path, t, flat_h, flat_v, flat_h + rng.normal(0, 0.003, len(t)), flat_v + rng.normal(0, 0.02, len(t)))
    out = tmp_path / "poor"
    assert main([path, "--out", str(out)] + ARGS) == 2
    err = capsys.readouterr().err
    assert "too little excitation to identify" in err or "hardly changes" in err
    assert not out.exists()


def test_corrupt_bag(tmp_path, capsys):
    path = tmp_path / "corrupt.bag"
    path.write_bytes(b"#ROSBAG V2.0\n" + os.urandom(3000))
    assert main([str(path), "--out", str(tmp_path / "c")]) == 2
    err = capsys.readouterr().err
    assert "not a readable bag" in err or "corrupt" in err


def test_config_file_for_topics(recording, tmp_path):
    cfg = tmp_path / "topics.yaml"
    cfg.write_text(yaml.safe_dump({"setpoint": {"topic": "/ctrl/command", "speed": "speed", "handlebar": "steer",
                                                "brake": "brake"},
                                   "measurement": {"topic": "/ctrl/feedback", "speed": "speed", "handlebar": "steer"},
                                   "stamp": "bag"}))
    assert main([recording[0], "--out", str(tmp_path / "cfg"), "--config", str(cfg), "--replay",
                 "--loops", "handlebar"]) == 0


def test_out_into_a_users_folder_replaces_only_its_own_files(recording, tmp_path):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("the user's notes")
    (out / "calibration.json").write_text("{}")
    assert main([recording[0], "--out", str(out), "--replay"] + ARGS) == 0
    assert (out / "notes.txt").read_text() == "the user's notes"
    assert json.loads((out / "calibration.json").read_text())["mode"] == "replay"
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temporary left behind


def test_out_that_is_a_file_is_refused(recording, tmp_path, capsys):
    out = tmp_path / "a_file"
    out.write_text("x")
    assert main([recording[0], "--out", str(out), "--replay"] + ARGS) == 2
    assert "is a file, not a folder" in capsys.readouterr().err and out.read_text() == "x"


def test_unstamped_setpoints_need_no_flag(recording, tmp_path, capsys):
    """A plain recording: the setpoints' headers were never set (stamp 0), the feedback's
    were. By default each message is timed by its header where set, else by the bag, and
    the tool says which topic was timed by the bag; the fit is the stamped recording's."""
    import json

    path, t, sp_h, sp_v, meas_h, meas_v = recording
    plain = str(tmp_path / "plain.bag")
    with rosbag.Bag(path) as src, rosbag.Bag(plain, "w") as dst:
        for topic, m, at in src.read_messages():
            if topic == "/ctrl/command":
                m.header.stamp = rospy.Time(0)
            dst.write(topic, m, at)
    assert main([plain, "--out", str(tmp_path / "p"), "--replay", "--loops", "handlebar"] + ARGS) == 0
    err = capsys.readouterr().err
    assert "/ctrl/command" in err and "bag's record time" in err and "/ctrl/feedback" not in err
    assert main([path, "--out", str(tmp_path / "s"), "--replay", "--loops", "handlebar"] + ARGS) == 0
    a = json.loads((tmp_path / "p" / "calibration.json").read_text())
    b = json.loads((tmp_path / "s" / "calibration.json").read_text())
    assert a["loops"]["handlebar"]["replay_rms"] == pytest.approx(b["loops"]["handlebar"]["replay_rms"], rel=1e-6)


def test_an_import_mapping_reads_raw_units(recording, tmp_path, capsys):
    """A PLC that logs raw units (mm/s, 1e-4 rad with the opposite sign, brake in percent)
    and unstamped commands: through the same import mapping replay and analyze use (its
    setpoint and state sections), the replay of the recording is the SI recording's."""
    path, t, sp_h, sp_v, meas_h, meas_v = recording
    raw = str(tmp_path / "raw.bag")
    with rosbag.Bag(path) as src, rosbag.Bag(raw, "w") as dst:
        for topic, m, at in src.read_messages():
            m.speed, m.steer = m.speed * 1000.0, -m.steer * 1e4
            if topic == "/ctrl/command":
                m.header.stamp = rospy.Time(0)
                m.brake *= 100.0
            dst.write(topic, m, at)
    mapping = {"setpoint": {"topic": "/ctrl/command", "stamp": "auto", "speed": {"field": "speed", "scale": 1e-3},
                            "handlebar": {"field": "steer", "scale": -1e-4}, "brake": {"field": "brake", "scale": 0.01}},
               "state": {"topic": "/ctrl/feedback", "wheel_speed": {"field": "speed", "scale": 1e-3},
                         "handlebar": {"field": "steer", "scale": -1e-4}}}
    mfile = tmp_path / "map.yaml"
    mfile.write_text(yaml.safe_dump(mapping))
    assert main([raw, "--out", str(tmp_path / "m"), "--replay", "--map", str(mfile)]) == 0
    assert main([path, "--out", str(tmp_path / "s"), "--replay"] + ARGS) == 0
    a = json.loads((tmp_path / "m" / "calibration.json").read_text())
    b = json.loads((tmp_path / "s" / "calibration.json").read_text())
    for loop in ("handlebar", "speed"):
        # the same to the report's rounding (5 digits): raw x scale is not exactly the SI value
        assert a["loops"][loop]["replay_rms"] == pytest.approx(b["loops"][loop]["replay_rms"], abs=2e-5), loop
    # refusals: a mapping without a setpoint section, a mapping mixed with the topic options
    del mapping["setpoint"]
    mfile.write_text(yaml.safe_dump(mapping))
    capsys.readouterr()
    assert main([raw, "--out", str(tmp_path / "x"), "--map", str(mfile)]) == 2
    assert "no 'setpoint' section" in capsys.readouterr().err
    assert main([raw, "--out", str(tmp_path / "x"), "--map", str(mfile)] + ARGS) == 2
    assert "replaces --config" in capsys.readouterr().err and not (tmp_path / "x").exists()


def test_a_recording_in_mismatched_units_is_warned():
    """calibrate --replay printed delay, rise and overshoot for a handlebar response 20x smaller
    than its setpoints, which were beyond the steering limit (degrees declared as radians),
    without a word."""
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_sim.calibration import Series, recording_warnings

    v = load_vehicle()
    t = np.arange(0.0, 20.0, 0.01)
    deg = np.where((t // 4) % 2 == 1, 20.0, -20.0)  # setpoints in degrees, read as radians
    measured = np.radians(deg) * 0.95
    w = recording_warnings("handlebar", Series(t, deg, measured, np.zeros_like(t)), v)
    assert len(w) == 2
    assert "beyond the vehicle's limits" in w[0] and "-20 .. 20 rad" in w[0]
    assert "different units or scales" in w[1]
    ok = recording_warnings("handlebar", Series(t, np.radians(deg), measured, np.zeros_like(t)), v)
    assert ok == []
    speed = recording_warnings("speed", Series(t, np.full_like(t, 36.0), np.full_like(t, 9.5), np.zeros_like(t)), v)
    assert "beyond the vehicle's limits" in speed[0]  # km/h for m/s
