"""The simulator core without ROS: physics properties, sensors, determinism, schedules."""
import math

import numpy as np
import pytest

from quadrivio_config import ConfigError, from_mapping, load_yaml
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import GRAVITY, load_vehicle
from quadrivio_sim.actuators import load_actuators
from quadrivio_sim.paths import package_file
from quadrivio_sim.script import ScriptRow, SetpointScript
from quadrivio_description.site import load_site
from quadrivio_sim.simulator import SimParams, Simulator, steps_per_period
from quadrivio_sim.world import Obstacle, quat_to_matrix, quat_to_rpy


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


@pytest.fixture(scope="module")
def actuators():
    return load_actuators(package_file("config", "actuators.yaml"))


def default_params(**changes):
    data = load_yaml(package_file("config", "sim.yaml"))
    data.update(changes)
    return from_mapping(SimParams, data, "sim.yaml")


def make_sim(vehicle, actuators, **changes):
    return Simulator(default_params(**changes), vehicle, actuators, build_urdf(vehicle))


def run(sim, seconds, keep=("ground_truth",)):
    out = {k: [] for k in keep}
    while sim.t < seconds - 1e-9:
        for name, sample in sim.step():
            if name in out:
                out[name].append(sample)
    return out


def test_rest_on_flat_ground(vehicle, actuators):
    sim = make_sim(vehicle, actuators)
    out = run(sim, 2.0, ("ground_truth", "imu", "mag", "gps"))
    gt = out["ground_truth"][-1]
    # base_link (rear axle centre) at the wheel radius minus the tyre's static deflection.
    assert gt.position[2] == pytest.approx(vehicle.wheel_radius, abs=0.03)
    assert max(abs(c) for c in gt.linear_velocity) < 0.01
    imu = out["imu"][-1]
    assert imu.specific_force == pytest.approx((0.0, 0.0, GRAVITY), abs=0.05)
    assert imu.angular_rate == pytest.approx((0.0, 0.0, 0.0), abs=1e-3)
    mag = out["mag"][-1]
    assert mag.field == pytest.approx(load_site().magnetic_field.enu(), abs=5e-7)
    gps = out["gps"][-1]
    R = quat_to_matrix(gt.orientation)
    expected = np.asarray(gt.position) + R @ np.asarray(vehicle.sensors["gps_link"].xyz)
    assert gps.position == pytest.approx(tuple(expected), abs=1e-3)


def test_sensor_rates(vehicle, actuators):
    sim = make_sim(vehicle, actuators)
    out = run(sim, 2.0, ("ground_truth", "imu", "mag", "gps", "scan", "plc_state", "joint_states"))
    assert len(out["imu"]) == 200
    assert len(out["mag"]) == 100
    assert len(out["gps"]) == 10
    assert len(out["scan"]) == 2 * 20
    assert len(out["ground_truth"]) == 100
    assert len(out["plc_state"]) == 99  # the 100th is on the PLC link (2 ms) until the next step
    stamps = [s.stamp for s in out["imu"]]
    assert np.allclose(np.diff(stamps), 0.01)


def _plc_deliveries(sim, seconds):
    out = []
    while sim.t < seconds - 1e-9:
        for name, sample in sim.step():
            if name == "plc_state":
                out.append((sim.t, sample.plc_time))
    return out


@pytest.mark.parametrize("delay,jitter", [(0.002, 0.0005), (0.013, 0.0), (0.025, 0.004)])
def test_the_plc_link_delays_states_to_the_first_step_after(vehicle, actuators, delay, jitter):
    """STATE frames leave at the first physics step at or after plc_time + the link's delay
    (a delay below a step arrives one step late), in order, with the same delays for the
    same seed, after a reset too."""
    plc = dict(load_yaml(package_file("config", "sim.yaml"))["plc"], latency={"delay": delay, "jitter": jitter})
    sim = make_sim(vehicle, actuators, plc=plc)
    got = _plc_deliveries(sim, 2.0)
    dt = sim.dt
    assert len(got) >= 100 - math.ceil((delay + 4 * jitter) / 0.02) - 1
    lag = np.array([t - pt for t, pt in got])
    assert np.all(lag >= delay - 4 * jitter - 1e-9) and np.all(lag > 0.0)
    if jitter == 0.0:
        assert np.allclose(lag, math.ceil(delay / dt - 1e-9) * dt)  # exactly the first step at or after
    else:
        assert np.all(lag < delay + 5 * jitter + dt)
    assert [pt for _, pt in got] == sorted(pt for _, pt in got)
    again = make_sim(vehicle, actuators, plc=plc)
    assert _plc_deliveries(again, 2.0) == got
    sim.reset()
    assert _plc_deliveries(sim, 2.0) == got


def test_no_plc_latency_delivers_in_the_same_step(vehicle, actuators):
    plc = dict(load_yaml(package_file("config", "sim.yaml"))["plc"], latency={"delay": 0.0, "jitter": 0.0})
    got = _plc_deliveries(make_sim(vehicle, actuators, plc=plc), 1.0)
    assert len(got) == 50 and all(abs(t - pt) < 1e-9 for t, pt in got)


def test_rate_must_divide_physics_step():
    with pytest.raises(ConfigError, match="'sensors.imu.rate' = 33.0 Hz is not a whole number"):
        steps_per_period(33.0, 0.005, "sensors.imu.rate")
    assert steps_per_period(100.0, 0.005, "x") == 2


def test_laser_sees_obstacle(vehicle, actuators):
    # A wall 8 m ahead of the front scanner, 10 m wide: the forward ray reads 8 m.
    laser_x = vehicle.sensors["laser_front"].xyz[0]
    wall = Obstacle("box", (laser_x + 8.0 + 0.5, 0.0), (1.0, 10.0, 2.0))
    sim = make_sim(vehicle, actuators, obstacles=[{"kind": "box", "xy": list(wall.xy), "size": list(wall.size)}])
    scans = [s for s in run(sim, 0.5, ("scan",))["scan"] if s.frame == "laser_front"]
    scan = scans[-1]
    mid = len(scan.ranges) // 2
    assert scan.ranges[mid] == pytest.approx(8.0, abs=0.03)
    rear = [s for s in run(sim, 1.0, ("scan",))["scan"] if s.frame == "laser_rear"][-1]
    assert math.isinf(rear.ranges[len(rear.ranges) // 2])  # nothing behind


def test_a_scan_cast_in_two_parts_reads_as_the_whole_rays(vehicle, actuators):
    """The rays that returned near in the last scan are cast a third of the way first, and on
    from there if they hit nothing (LaserSensor.cast): on rough ground among posts, boxes and
    a person, from poses that jump around (near rays going far and far ones near), with a
    scanner of our own and one unlike it (1081 rays all around, 80 m), every ray reads as
    the whole ray cast at once but for Bullet's single-precision rounding: micrometres, up to
    6 mm where a ray grazes the rough ground (the laser's own noise is 1 cm)."""
    from quadrivio_sim.sensors import LaserParams, LaserSensor

    rng = np.random.default_rng(11)
    obstacles = [{"kind": str(rng.choice(["box", "cylinder"])), "xy": [float(v) for v in rng.uniform(-25, 25, 2)],
                  "size": [float(rng.uniform(0.1, 1.5)), float(rng.uniform(0.2, 3.0)), 2.0]} for _ in range(40)]
    terrain = {"kind": "procedural", "size": 80.0, "roughness": 0.1, "resolution": 0.5}
    actors = [{"name": "p", "kind": "person", "waypoints": [[3.0, 2.0]]}]
    sim = make_sim(vehicle, actuators, terrain=terrain, obstacles=obstacles, actors=actors)
    world = sim.world
    lasers = [sim.lasers[0], LaserSensor(world, LaserParams(fov=2 * math.pi, samples=1081, range_min=0.05,
                                                            range_max=80.0), "laser_front")]
    split = resumed = 0
    diffs = []
    for k in range(60):
        yaw, pitch = rng.uniform(-math.pi, math.pi), rng.normal(0.0, 0.05)
        if k % 3 == 0:  # a jump: some near rays now go far, far ones come near
            pos = np.array([*rng.uniform(-20.0, 20.0, 2), rng.uniform(0.3, 1.5)])
        else:
            pos = pos + rng.normal(0.0, 0.3, 3) * [1.0, 1.0, 0.1]
        c, s_, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
        R = np.array([[c * cp, -s_, c * sp], [s_ * cp, c, s_ * sp], [-sp, 0.0, cp]])
        for laser in lasers:
            starts, ends = laser.starts @ R.T + pos, laser.ends @ R.T + pos
            near = laser._near.copy()
            got = laser.cast(starts, ends)
            whole = np.asarray(world.ray_batch(starts, ends))
            assert np.array_equal(got >= 1.0, whole >= 1.0), k
            diff = np.abs(got - whole) * laser.span  # [m]
            assert diff.max() <= 0.01, k
            diffs.append(diff)
            split += int(near.any())
            resumed += int((near & (whole >= laser.NEAR)).any())
    assert split > 60 and resumed > 20  # both parts were exercised
    assert np.percentile(np.concatenate(diffs), 99.0) <= 1e-4


def _circle_radius(xs, ys):
    A = np.c_[2 * xs, 2 * ys, np.ones_like(xs)]
    c = np.linalg.lstsq(A, xs ** 2 + ys ** 2, rcond=None)[0]
    return math.sqrt(c[2] + c[0] ** 2 + c[1] ** 2)


@pytest.mark.parametrize("handlebar", [0.15, -0.3])
def test_constant_handlebar_drives_circle(vehicle, actuators, handlebar):
    sim = make_sim(vehicle, actuators)
    sim.script = SetpointScript([ScriptRow(0.0, 1.5, handlebar, 0.0)])
    gts = run(sim, 40.0)["ground_truth"]
    pts = np.array([g.position[:2] for g in gts if g.stamp > 10.0])
    R = _circle_radius(pts[:, 0], pts[:, 1])
    assert R == pytest.approx(vehicle.wheelbase / math.tan(abs(handlebar)), rel=0.05)
    yaw_rate = gts[-1].angular_velocity[2]
    assert math.copysign(1, yaw_rate) == math.copysign(1, handlebar)  # positive handlebar turns left


def test_same_seed_same_run(vehicle, actuators):
    script = SetpointScript([ScriptRow(0.0, 2.0, 0.0, 0.0), ScriptRow(3.0, 3.0, 0.25, 0.0),
                             ScriptRow(6.0, 1.0, -0.2, 0.0), ScriptRow(9.0, 0.0, 0.0, 0.5)])
    terrain = {"kind": "procedural", "size": 60.0, "roughness": 0.04, "resolution": 0.5}
    traces = []
    for _ in range(2):
        sim = make_sim(vehicle, actuators, seed=7, terrain=terrain)
        sim.script = script
        gts = run(sim, 12.0)["ground_truth"]
        traces.append(np.array([g.position + g.orientation for g in gts]))
        sim.close()
    assert traces[0].shape == traces[1].shape
    assert np.array_equal(traces[0], traces[1])  # bit for bit
    assert np.ptp(traces[0][:, 0]) > 10.0  # it did drive


def test_reset_returns_to_start(vehicle, actuators):
    sim = make_sim(vehicle, actuators)
    sim.script = SetpointScript([ScriptRow(0.0, 2.0, 0.1, 0.0)])
    run(sim, 3.0)
    sim.script = None
    sim.reset()
    assert sim.t == 0.0
    gt = run(sim, 0.5)["ground_truth"][-1]
    assert gt.position[:2] == pytest.approx((0.0, 0.0), abs=0.02)
    assert abs(quat_to_rpy(gt.orientation)[2]) < 1e-3


def test_a_reset_run_repeats_a_fresh_one(vehicle, actuators):
    """After a reset the simulator runs as a fresh one does, every output to the bit: the
    lasers do not cast the rays that returned near before it short first
    (LaserSensor.cast), and the noise, the GPS, the actors and the PLC link start over; on
    rough ground among posts, driving, with a walking person it touches."""
    rng = np.random.default_rng(5)
    obstacles = [{"kind": "cylinder", "xy": [float(v) for v in rng.uniform(-6, 6, 2)], "size": [0.3, 0.3, 2.0]}
                 for _ in range(12)]
    terrain = {"kind": "procedural", "size": 60.0, "roughness": 0.1, "resolution": 0.5}
    actors = [{"name": "p", "kind": "person", "waypoints": [[3.0, 2.0], [3.0, -2.0]], "speed": 1.0}]

    def outputs(sim):
        sim.script = SetpointScript([ScriptRow(0.0, 1.5, 0.2, 0.0)])
        out = {}
        while sim.t < 3.0 - 1e-9:
            for name, sample in sim.step():
                out.setdefault(name, []).append(repr(sample))
        sim.script = None
        return out

    sim = make_sim(vehicle, actuators, terrain=terrain, obstacles=obstacles, actors=actors)
    first = outputs(sim)
    assert outputs(make_sim(vehicle, actuators, terrain=terrain, obstacles=obstacles, actors=actors)) == first
    assert {"scan", "gps", "imu", "actors", "contact", "plc_state"} <= set(first)
    sim.reset()
    assert outputs(sim) == first


def test_heightfield_spawn_and_slope(vehicle, actuators):
    terrain = {"kind": "procedural", "size": 60.0, "roughness": 0.0, "slope": [0.1, 0.0], "flat_radius": 0.0}
    sim = make_sim(vehicle, actuators, terrain=terrain, spawn={"x": 5.0, "y": 0.0, "yaw": 0.0})
    gt = run(sim, 3.0)["ground_truth"][-1]
    ground = sim.world.ground_height(gt.position[0], gt.position[1])
    assert ground == pytest.approx(0.1 * gt.position[0], abs=0.05)
    assert gt.position[2] - ground == pytest.approx(vehicle.wheel_radius, abs=0.06)
    pitch = quat_to_rpy(gt.orientation)[1]
    assert pitch == pytest.approx(-math.atan(0.1), abs=0.02)  # nose up on an uphill slope (REP-103)
    assert abs(gt.linear_velocity[0]) < 0.05  # the brake holds it on the slope
