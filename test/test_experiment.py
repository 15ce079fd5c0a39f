"""System test through the user's commands: the paper's figure-eight experiment in
simulation end to end (`experiment`), and `analyze` on the same bag without ground truth."""
import json
import os
import subprocess

import pytest
import rosbag
from conftest import short_scenario

from quadrivio.metrics import CONTRACT_KEYS, PLANNED_KEYS

pytestmark = pytest.mark.system

# make test runs these tests two at a time (pytest-xdist, --dist loadgroup): the ones that
# read the figure-eight run share one worker, and its fixture lives for the session, so that
# it runs once whatever that worker runs in between
SHARES_THE_EIGHT = pytest.mark.xdist_group("figure_eight")
PLOTS = ("trajectory.png", "errors.png", "control.png", "calibration.png")


@pytest.fixture(scope="session")
def figure_eight(tmp_path_factory):
    out = tmp_path_factory.mktemp("figure_eight")
    r = subprocess.run(["rosrun", "quadrivio", "experiment", "figure_eight", "--out", str(out),
                        "--wall-timeout", "300"], capture_output=True, text=True, timeout=420)
    return out, r


@SHARES_THE_EIGHT
def test_figure_eight_is_followed_with_noisy_faulty_sensors(figure_eight):
    out, r = figure_eight
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    m = json.loads((out / "metrics.json").read_text())
    assert set(CONTRACT_KEYS) <= set(m)
    assert m["completed"] is True and m["scenario"] == "figure_eight" and m["seed"] == 1
    # The eight is ~96 m at 2 m/s.
    assert 45.0 < m["sim_duration_s"] < 80.0
    # Localization beats its GPS (multipath bursts and drift included) and stays on the path.
    # Its absolute error is bounded below by the receiver's slow drift (0.3 m here, through
    # a 17 s outage), which no GPS-only localization can see.
    assert m["loc_rmse_m"] < 0.45 and m["loc_max_m"] < 0.8
    # Not dragged by multipath: no worse than the fixes (whose slow drift it cannot see and
    # shares: 0.31 m against 0.32 in this run), far better at the tail.
    assert m["loc_rmse_m"] < m["gps_rmse_m"] + 0.05
    assert m["loc_heading_rmse_deg"] < 2.0
    assert m["pred_rmse_m"] < 0.35
    assert m["xte_rmse_m"] < 0.3 and m["xte_max_m"] < 0.8
    assert 0.5 < m["max_lateral_accel_mps2"] < 3.0  # 2 m/s on a 6.25 m radius is 0.64 m/s^2
    for name in PLOTS:
        assert (out / name).stat().st_size > 20000, name
    info = json.loads((out / "run_info.json").read_text())
    assert info["outcome"] == "completed" and info["seed"] == 1
    assert all(m[k] is None for k in PLANNED_KEYS)  # no map, no goal: a reference path


@SHARES_THE_EIGHT
def test_analyze_a_bag_without_ground_truth(figure_eight, tmp_path):
    """What a bag from the real vehicle gives: no ground truth, so those keys are null."""
    out, r = figure_eight
    assert r.returncode == 0
    real = str(tmp_path / "real.bag")
    with rosbag.Bag(str(out / "run.bag")) as src, rosbag.Bag(real, "w") as dst:
        for topic, msg, t in src.read_messages(raw=True):
            if not topic.startswith("/ground_truth") and not topic.startswith("/sim/"):
                dst.write(topic, msg, t, raw=True)
    r2 = subprocess.run(["rosrun", "quadrivio", "analyze", real, "--out", str(tmp_path / "an")],
                        capture_output=True, text=True, timeout=300)
    assert r2.returncode == 0, r2.stderr[-3000:]
    m = json.loads((tmp_path / "an" / "metrics.json").read_text())
    for key in ("loc_rmse_m", "loc_p95_m", "loc_max_m", "loc_heading_rmse_deg", "pred_rmse_m", "gps_rmse_m",
                "xte_rmse_m", "xte_max_m", "max_lateral_accel_mps2"):
        assert m[key] is None, key
    online = json.loads((out / "metrics.json").read_text())
    assert m["completed"] is True and m["gps_fix_fraction"] == pytest.approx(online["gps_fix_fraction"], abs=0.01)
    assert 0.3 < m["gps_fix_fraction"] < 1.0
    assert (tmp_path / "an" / "trajectory.png").exists()


def test_analyze_rejects_a_corrupt_bag(tmp_path):
    bad = tmp_path / "bad.bag"
    bad.write_bytes(b"#ROSBAG V2.0\n" + os.urandom(500))
    r = subprocess.run(["rosrun", "quadrivio", "analyze", str(bad), "--out", str(tmp_path / "an")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0 and "bad.bag" in r.stderr
    assert not (tmp_path / "an" / "metrics.json").exists()


def test_rough_terrain_runs_end_to_end(tmp_path):
    """Beyond the paper: the eight over bumps and a slope, GPS outages and multipath."""
    r = subprocess.run(["rosrun", "quadrivio", "experiment", "rough_terrain", "--out", str(tmp_path),
                        "--wall-timeout", "300"], capture_output=True, text=True, timeout=420)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    assert m["completed"] is True and m["scenario"] == "rough_terrain"
    assert m["loc_rmse_m"] < 0.6 and m["xte_max_m"] < 1.0  # measured 0.25 and 0.48
    assert m["gps_fix_fraction"] < 0.97  # the scenario's outages happened
    with rosbag.Bag(str(tmp_path / "run.bag")) as bag:
        levels = [msg.level for _, msg, _ in bag.read_messages(topics=["/safety/rollover"])]
        z = [msg.pose.pose.position.z for _, msg, _ in bag.read_messages(topics=["/ground_truth/odom"])]
    assert levels and max(levels) < 2  # the roll-over monitor watched and never tripped
    assert max(z) - min(z) > 0.5  # it was not flat ground


def _odom(path):
    with rosbag.Bag(path) as bag:
        return [(m.header.stamp.to_nsec(), m.pose.pose.position.x, m.pose.pose.position.y, m.pose.pose.orientation.z,
                 tuple(m.pose.covariance)) for _, m, _ in bag.read_messages(topics=["/localization/odom"])]


@SHARES_THE_EIGHT
def test_replay_is_deterministic_and_as_good_as_online(figure_eight, tmp_path):
    out, r = figure_eight
    assert r.returncode == 0
    cal = subprocess.run(["rospack", "find", "quadrivio_sim"], capture_output=True, text=True).stdout.strip()
    cal = os.path.join(cal, "config", "mag_calibration.yaml")  # what sim.launch loads
    outs = []
    for k in range(2):
        dst = str(tmp_path / f"replay{k}.bag")
        rr = subprocess.run(["rosrun", "quadrivio_localization", "replay", str(out / "run.bag"), "--out", dst,
                             "--params", cal, "--quiet"], capture_output=True, text=True, timeout=300)
        assert rr.returncode == 0, rr.stderr[-3000:]
        outs.append(_odom(dst))
    assert len(outs[0]) > 500 and outs[0] == outs[1]  # message for message
    online = json.loads((out / "metrics.json").read_text())
    r2 = subprocess.run(["rosrun", "quadrivio", "analyze", str(tmp_path / "replay0.bag"), "--out", str(tmp_path / "an")],
                        capture_output=True, text=True, timeout=300)
    assert r2.returncode == 0, r2.stderr[-3000:]
    m = json.loads((tmp_path / "an" / "metrics.json").read_text())
    # Offline the smoother never runs late, so it is at least about as good as online.
    assert m["loc_rmse_m"] < max(1.2 * online["loc_rmse_m"], online["loc_rmse_m"] + 0.03)
    assert m["loc_heading_rmse_deg"] < 2.0


def test_replay_bad_input(tmp_path):
    missing = subprocess.run(["rosrun", "quadrivio_localization", "replay", str(tmp_path / "none.bag"),
                              "--out", str(tmp_path / "o.bag")], capture_output=True, text=True, timeout=60)
    assert missing.returncode == 2 and "none.bag: file not found" in missing.stderr
    empty = str(tmp_path / "nogps.bag")
    from std_msgs.msg import String
    with rosbag.Bag(empty, "w") as bag:
        bag.write("/chatter", String(data="hi"))
    r = subprocess.run(["rosrun", "quadrivio_localization", "replay", empty, "--out", str(tmp_path / "o.bag")],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2 and "no gps topic /gps/fix" in r.stderr and "/chatter" in r.stderr
    assert not (tmp_path / "o.bag").exists() and not list(tmp_path.glob(".replay-*"))


def test_an_excitation_run_calibrates_back_to_the_simulators_loops(tmp_path):
    """experiment drives the excitation program (shortened here), and calibrate identifies
    the simulator's own handlebar and speed loops from the recording (the paper's Fig. 4
    procedure, from a plain recording: the setpoints on /vehicle/setpoint/auto, the
    responses on /vehicle/state)."""
    import yaml

    from quadrivio.scenario import scenarios_dir
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.paths import package_file

    scenario = yaml.safe_load(open(os.path.join(scenarios_dir(), "excitation.yaml")))
    scenario["excitation"] = {"settle": 2.0, "handlebar_steps": [0.1, -0.1, 0.3, -0.3, 0.0, 0.05, -0.2, 0.0],
                              "handlebar_hold": 1.5, "sweep_duration": 6.0, "speed_steps": [1.0, 2.5, 1.5, 0.0, 2.0, 0.0],
                              "speed_hold": 3.0}
    scenario["run"]["max_duration"] = 48.0
    sfile = tmp_path / "excitation.yaml"
    sfile.write_text(yaml.safe_dump(scenario))
    out = tmp_path / "exc"
    r = subprocess.run(["rosrun", "quadrivio", "experiment", str(sfile), "--out", str(out), "--wall-timeout", "300"],
                       capture_output=True, text=True, timeout=420)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    r = subprocess.run(["rosrun", "quadrivio_sim", "calibrate", str(out / "run.bag"), "--out", str(tmp_path / "cal")],
                       capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    report = json.loads((tmp_path / "cal" / "calibration.json").read_text())
    truth = load_actuators(package_file("config", "actuators.yaml"))
    h, s = report["loops"]["handlebar"], report["loops"]["speed"]
    assert h["identified"]["pid.kp"] == pytest.approx(truth.handlebar.pid.kp, rel=0.1)
    assert h["identified"]["servo_tau"] == pytest.approx(truth.handlebar.servo_tau, abs=0.02)
    assert h["identified"]["dead_time"] == pytest.approx(truth.handlebar.dead_time, abs=0.021)
    assert s["identified"]["max_accel"] == pytest.approx(truth.speed.max_accel, rel=0.1)
    assert s["identified"]["max_decel"] == pytest.approx(truth.speed.max_decel, rel=0.1)
    assert h["replay_rms"] < 0.01 and s["replay_rms"] < 0.1


def test_a_closed_loop_campaign_through_ros_runs_the_whole_stack_per_run(tmp_path):
    """`campaign --closed-loop --ros`: each run is an `experiment` (the stack on its own master),
    its metrics in the table, its folder (bag, metrics.json, plots) kept under runs/."""
    path = short_scenario(tmp_path, max_duration=25.0)
    out = tmp_path / "out"
    r = subprocess.run(["rosrun", "quadrivio", "campaign", path, "--closed-loop", "--ros", "--seeds", "1", "--rtf",
                        "1", "--out", str(out)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    result = json.loads((out / "campaign.json").read_text())
    assert result["meta"]["mode"] == "closed loop (ROS)" and result["meta"]["failures"] == []
    (run,) = result["runs"]
    assert run["scenario"] == "short_rtk" and run["seed"] == 0 and run["end"] == "completed"  # its 25 s
    assert 0.0 < run["rmse_m"] < 1.0 and 0.0 < run["gps_rmse_m"] < 1.0
    folder = out / "runs" / "short_rtk_s0"
    m = json.loads((folder / "metrics.json").read_text())
    assert m["seed"] == 0 and 20.0 < m["sim_duration_s"] < 30.0
    assert "| short_rtk | 1 |" in (out / "campaign.md").read_text()
    assert (folder / "run.bag").exists()
    # the campaign's plots, the run's track and errors read back from its bag
    assert "plot_error" not in run, run.get("plot_error")
    for name in ("campaign.png", "short_rtk_errors.png", "short_rtk_tracks.png"):
        assert (out / name).stat().st_size > 20000, name


@SHARES_THE_EIGHT
def test_real_launch_against_the_stand_in_is_sim_launch(figure_eight, tmp_path):
    """The paper's promise (section 3.3): the stack cannot tell the simulator from the
    vehicle. `experiment --stack real` runs sim.launch hardware:=true (the vehicle's stand-in:
    simulator, PLC on TCP, NMEA GPS on a pseudo-terminal, IMU, magnetometer and lasers as
    their drivers publish them) and real.launch unchanged against it on the same master. Its
    bag has the same topics as sim.launch's, with the same types, frames, rates (5 %) and
    covariance conventions, and it drives the figure eight to completion as well."""
    from quadrivio import parity
    from quadrivio.ros.bag import topic_profile

    sim_out, r0 = figure_eight
    assert r0.returncode == 0
    r = subprocess.run(["rosrun", "quadrivio", "experiment", "figure_eight", "--stack", "real", "--out", str(tmp_path),
                        "--wall-timeout", "300"], capture_output=True, text=True, timeout=420)
    assert r.returncode == 0, r.stdout[-3000:] + r.stderr[-3000:]
    m = json.loads((tmp_path / "metrics.json").read_text())
    ref = json.loads((sim_out / "metrics.json").read_text())
    assert m["completed"] is True and json.loads((tmp_path / "run_info.json").read_text())["stack"] == "real"
    problems = parity.compare(topic_profile(str(sim_out / "run.bag")), topic_profile(str(tmp_path / "run.bag")))
    assert problems == []
    # the GPS through NMEA and the real driver, the rest the same: as good within noise
    assert m["loc_rmse_m"] < ref["loc_rmse_m"] + 0.15 and m["xte_rmse_m"] < 0.3
