"""Terrain: DEM images and procedural ground load, and the vehicle behaves plausibly on them."""
import math

import matplotlib
import numpy as np
import pytest

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from quadrivio_config import ConfigError, from_mapping, load_yaml  # noqa: E402
from quadrivio_description.urdf import build_urdf  # noqa: E402
from quadrivio_description.vehicle import load_vehicle  # noqa: E402
from quadrivio_sim.actuators import load_actuators  # noqa: E402
from quadrivio_sim.paths import package_file  # noqa: E402
from quadrivio_sim.script import ScriptRow, SetpointScript  # noqa: E402
from quadrivio_sim.simulator import SimParams, Simulator  # noqa: E402
from quadrivio_terrain.terrain import TerrainParams, build_heightfield, read_dem  # noqa: E402
from quadrivio_sim.world import quat_to_rpy  # noqa: E402


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


def make_sim(vehicle, **changes):
    data = load_yaml(package_file("config", "sim.yaml"))
    data.update(changes)
    return Simulator(from_mapping(SimParams, data, "test"), vehicle, load_actuators(package_file("config", "actuators.yaml")),
                     build_urdf(vehicle))


def write_pgm(path, img):
    h, w = img.shape
    with open(path, "wb") as fh:
        fh.write(f"P5\n# test DEM\n{w} {h}\n255\n".encode())
        fh.write(img.astype(np.uint8).tobytes())


def ramp_image(n=41):
    # Row 0 is the image's top edge: north. Brightness grows eastwards (with x).
    return np.tile(np.linspace(0, 255, n), (n, 1))


@pytest.mark.parametrize("ext", ["pgm", "png"])
def test_dem_image_heights(tmp_path, ext):
    img = ramp_image()
    img[0, :] = 255  # a bright northern edge row: must end up at the top (largest y)
    path = str(tmp_path / f"dem.{ext}")
    if ext == "pgm":
        write_pgm(path, img)
    else:
        plt.imsave(path, img, cmap="gray", vmin=0, vmax=255)
    hf = build_heightfield(TerrainParams(kind="image", image=path, resolution=0.5, height_range=4.0), None)
    assert hf.shape == (41, 41)
    assert hf.height(-10.0, 0.0) == pytest.approx(0.0, abs=0.05)  # west edge: black
    assert hf.height(10.0, 0.0) == pytest.approx(4.0, abs=0.05)  # east edge: white
    assert hf.height(0.0, 0.0) == pytest.approx(2.0, abs=0.05)
    assert hf.height(-10.0, 10.0) == pytest.approx(4.0, abs=0.05)  # north edge row
    assert hf.gradient(0.0, 0.0)[0] == pytest.approx(4.0 / 20.0, abs=0.015)  # 8-bit steps of the ramp


def test_dem_errors(tmp_path):
    with pytest.raises(ConfigError, match="nope.png: file not found"):
        read_dem(str(tmp_path / "nope.png"))
    bad = tmp_path / "bad.pgm"
    bad.write_bytes(b"P2\n2 2\n255\n0 0 0 0\n")
    with pytest.raises(ConfigError, match="bad.pgm: cannot read"):
        read_dem(str(bad))


def test_vehicle_spawns_on_a_dem(vehicle, tmp_path):
    path = str(tmp_path / "dem.pgm")
    write_pgm(path, ramp_image())
    sim = make_sim(vehicle, terrain={"kind": "image", "image": path, "resolution": 0.5, "height_range": 2.0},
                   spawn={"x": 2.0, "y": 1.0, "yaw": 0.0})
    while sim.t < 2.0:
        sim.step()
    pos, orn, _, _ = sim.world.base_state()
    assert pos[2] - sim.world.ground_height(pos[0], pos[1]) == pytest.approx(vehicle.wheel_radius, abs=0.05)
    assert quat_to_rpy(orn)[1] == pytest.approx(-math.atan(0.1), abs=0.02)  # 2 m over 20 m: nose up
    assert all(sim.world.wheel_contacts())


def test_procedural_roughness_rms():
    p = TerrainParams(kind="procedural", size=100.0, resolution=0.5, roughness=0.07, flat_radius=0.0)
    hf = build_heightfield(p, np.random.default_rng(3))
    assert hf.z.std() == pytest.approx(0.07, rel=0.02)
    same = build_heightfield(p, np.random.default_rng(3))
    assert np.array_equal(hf.z, same.z)


def test_rough_ground_drive_is_plausible(vehicle):
    terrain = {"kind": "procedural", "size": 120.0, "roughness": 0.05, "wavelength": 3.0, "flat_radius": 3.0}
    sim = make_sim(vehicle, terrain=terrain, seed=11)
    sim.script = SetpointScript([ScriptRow(0.0, 2.0, 0.0, 0.0)])
    susp, contacts, rp = [], [], []
    start = None
    while sim.t < 25.0:
        for name, s in sim.step():
            if name == "ground_truth":
                if start is None and s.stamp >= 5.0:
                    start = s.position
                rp.append(quat_to_rpy(s.orientation)[:2])
        if sim.steps % 5 == 0 and sim.t > 5.0:
            susp.append(sim.world.suspension_positions)
            contacts.append(sim.world.wheel_contacts())
    end = sim.world.base_state()[0]
    travelled = math.hypot(end[0] - start[0], end[1] - start[1])
    assert travelled == pytest.approx(2.0 * 20.0, rel=0.15)  # keeps its speed over the bumps
    assert np.all(np.isfinite(susp))
    assert np.max(np.abs(rp)) < 0.25  # no wild attitude
    assert np.mean(contacts) > 0.9  # wheels stay on the ground
    q = np.array(susp)
    assert q.std(axis=0).min() > 0.003  # the suspension works
    at_stop = (q >= [0.10, 0.10, 0.12, 0.12]) | (q <= [-0.08, -0.08, -0.10, -0.10])
    assert at_stop.mean() < 0.05  # and rarely hits its stops


def test_side_slope_spawn_follows_terrain(vehicle):
    terrain = {"kind": "procedural", "size": 60.0, "roughness": 0.0, "slope": [0.0, 0.3], "flat_radius": 0.0}
    sim = make_sim(vehicle, terrain=terrain)
    while sim.t < 2.0:
        sim.step()
    roll, pitch, _ = quat_to_rpy(sim.world.base_state()[1])
    # Left side up on a slope rising to the left, plus the body's roll on its springs: the
    # suspension acts vertically at the wheels, so the roll axis is on the ground and
    # body roll = m_s g h sin(phi) / K_roll with K_roll = (k_f t_f^2 + k_r t_r^2) / 2.
    phi = math.atan(0.3)
    k_roll = 0.5 * (vehicle.suspension.front.stiffness * vehicle.front_track ** 2 +
                    vehicle.suspension.rear.stiffness * vehicle.rear_track ** 2)
    body_roll = vehicle.chassis_mass * 9.81 * vehicle.body.com_height * math.sin(phi) / k_roll
    assert roll == pytest.approx(phi + body_roll, abs=0.01)
    q = sim.world.suspension_positions
    assert q[0] < 0 < q[1] and q[2] < 0 < q[3]  # uphill (left) wheels droop, downhill ones compress
    assert abs(pitch) < 0.02
    assert all(sim.world.wheel_contacts())


def test_climbs_a_20_percent_slope(vehicle):
    terrain = {"kind": "procedural", "size": 200.0, "roughness": 0.0, "slope": [0.2, 0.0], "flat_radius": 0.0}
    sim = make_sim(vehicle, terrain=terrain)
    sim.script = SetpointScript([ScriptRow(0.0, 2.0, 0.0, 0.0)])
    while sim.t < 12.0:
        sim.step()
    v = sim.world.base_state()[2]
    assert math.hypot(v[0], v[1]) == pytest.approx(2.0 * math.cos(math.atan(0.2)) / math.cos(math.atan(0.2)), rel=0.1)


def test_solid_rear_axle_keeps_driving_over_big_bumps(vehicle):
    """The rough-terrain scenario's ground, turning: through an open differential a rear
    wheel that lifts spins away with the torque and the vehicle stalls (it did, before the
    axle was locked); on the ATV's solid axle both rear wheels turn together."""
    terrain = {"kind": "procedural", "size": 80.0, "roughness": 0.12, "wavelength": 3.0, "slope": [0.06, 0.02],
               "flat_radius": 2.0, "friction": 0.7}
    sim = make_sim(vehicle, terrain=terrain, seed=11)
    sim.script = SetpointScript([ScriptRow(0.0, 1.5, 0.2, 0.0)])  # a 6 m radius circle over the bumps
    rates, dist, last = [], 0.0, None
    while sim.t < 30.0:
        sim.step()
        if sim.steps % 10 == 0:
            rates.append(sim.world.qd[4:8])
            p = sim.world.base_state()[0]
            if last is not None:
                dist += math.hypot(p[0] - last[0], p[1] - last[1])
            last = p
    rates = np.array(rates)
    # [rad/s] One shaft, slipping above drivetrain.axle_torque_limit (100 N m): a limited
    # slip. Mean difference here 0.23 (p95 0.73); through an open differential 0.72 (max
    # 3.7), and in the experiment a lifted wheel spun at 11.6 rad/s while the other stood.
    diff = np.abs(rates[:, 2] - rates[:, 3])
    assert diff.mean() < 0.4 and diff.max() < 2.0
    assert np.ptp(rates[:, 0] - rates[:, 1]) > 0.5  # the undriven front wheels turn freely
    assert dist > 0.8 * 1.5 * 28.0  # [m] keeps going (accelerating for the first 2 s)


@pytest.mark.parametrize("drive", ["4wd", "4wd_locked"])
def test_four_wheel_drive_modes(vehicle, drive):
    from quadrivio_config import replace_nested

    v = replace_nested(vehicle, {"drivetrain": {"drive": drive}})
    sim = make_sim(v, terrain={"kind": "procedural", "size": 200.0, "roughness": 0.0, "slope": [0.2, 0.0],
                               "flat_radius": 0.0})
    sim.script = SetpointScript([ScriptRow(0.0, 2.0, 0.3, 0.0)])
    spread = []
    while sim.t < 10.0:
        sim.step()
        if sim.t > 5.0:
            qd = sim.world.qd[4:8]
            spread.append((abs(qd[0] - qd[1]), abs(qd[0] - qd[2])))
    spread = np.array(spread)
    if drive == "4wd_locked":
        assert spread[:, 1].mean() < 0.2  # front and rear shafts coupled (0.14; 0.27 in 4wd)
    else:
        assert spread[:, 0].mean() > 1.0  # the open front differential: the wheels differ in the turn (1.66)
    v_now = sim.world.base_state()[2]
    assert math.hypot(v_now[0], v_now[1]) == pytest.approx(2.0, rel=0.15)  # climbs 20 % while turning


def test_the_planner_rebuilds_the_simulated_ground(vehicle):
    """The planner's slope cost (planner node, terrain_from_scenario) uses the same ground
    the simulator built: build_heightfield(p, default_rng(seed)) is the world's heightfield."""
    terrain = {"kind": "procedural", "size": 40.0, "resolution": 0.5, "roughness": 0.1, "slope": [0.05, 0.0]}
    sim = make_sim(vehicle, terrain=terrain, seed=17)
    again = build_heightfield(from_mapping(TerrainParams, terrain, "test"), np.random.default_rng(17))
    assert np.array_equal(sim.world.heightfield.z, again.z)
    xs, ys = np.array([-3.2, 0.0, 7.7]), np.array([1.1, -4.0, 9.9])
    assert np.allclose(again.heights(xs, ys), [sim.world.ground_height(x, y) for x, y in zip(xs, ys)])
    sim.close()


@pytest.mark.parametrize("drive,slope,command", [("2wd", 0.35, 2.0), ("4wd", -0.35, 2.0)])
def test_the_speed_loop_brakes_a_runaway_on_a_steep_grade(vehicle, drive, slope, command):
    """On a 35 % grade the vehicle cannot hold the command (2wd uphill slips back; downhill
    gravity beats engine braking): the PLC's loop must brake hard, as the real one does,
    instead of rolling back or running away while the banded ramp follows the vehicle."""
    import dataclasses

    v = dataclasses.replace(vehicle, drivetrain=dataclasses.replace(vehicle.drivetrain, drive=drive))
    terrain = {"kind": "procedural", "size": 200.0, "roughness": 0.0, "slope": [slope, 0.0], "flat_radius": 0.0}
    sim = make_sim(v, terrain=terrain)
    sim.script = SetpointScript([ScriptRow(0.0, command, 0.0, 0.0)])
    x0 = sim.world.base_state()[0][0]
    speeds, xs = [], []
    while sim.t < 15.0:
        sim.step()
        pos, _, vel = sim.world.base_state()[:3]
        xs.append(pos[0] - x0)
        speeds.append(math.copysign(math.hypot(vel[0], vel[1]), vel[0]))
    margin = load_actuators(package_file("config", "actuators.yaml")).speed.overspeed_margin
    assert min(speeds) > -(margin + 0.6), f"rolled back at {-min(speeds):.2f} m/s"
    assert max(speeds) < command + margin + 0.6, f"ran away at {max(speeds):.2f} m/s"
    assert min(xs) > -3.0, f"rolled back {-min(xs):.1f} m"


def test_a_few_heights_are_the_many_heights_bit_for_bit():
    """Heightfield.heights answers up to four points in plain Python (numpy's overhead was most
    of the guard's cost for its two): the same numbers as the array path, edges and outside
    the grid included, and a NaN point still goes the array way."""
    hf = build_heightfield(from_mapping(TerrainParams, {"kind": "procedural", "size": 20.0, "resolution": 0.5,
                                                        "roughness": 0.1, "slope": [0.05, 0.02]}, "test"),
                           np.random.default_rng(3))
    rng = np.random.default_rng(4)
    xs, ys = rng.uniform(-14.0, 14.0, 40), rng.uniform(-14.0, 14.0, 40)  # some beyond the 20 m grid
    xs[:2], ys[:2] = [-10.0, 10.0], [10.0, -10.0]  # its corners
    many = hf.heights(xs, ys)
    for k in range(0, 40, 4):
        for n in (1, 2, 3, 4):
            assert np.array_equal(hf.heights(xs[k:k + n], ys[k:k + n]), many[k:k + n])
    with np.errstate(invalid="ignore"), pytest.raises(IndexError):  # the array path's answer, not a ValueError
        hf.heights(np.array([0.0, math.nan]), np.array([0.0, 0.0]))


def test_level_ground_answers_what_the_bilinear_sum_answers():
    """The flat site's known DEM (a level grid at 0) answers 0 without the arithmetic: the
    same numbers as the bilinear path, inside, outside and at the edges, scalars and arrays;
    a grid with one raised cell is not level; a NaN point still goes the array way."""
    from quadrivio_terrain.terrain import Heightfield, known_heightfield

    level = known_heightfield(from_mapping(TerrainParams, {"kind": "flat"}, "test"), np.random.default_rng(0))
    assert level.level
    plain = Heightfield(level.z.copy(), level.res)
    plain.level = False  # the bilinear path on the same grid
    rng = np.random.default_rng(5)
    xs, ys = rng.uniform(-300.0, 300.0, 200), rng.uniform(-300.0, 300.0, 200)
    xs[:2], ys[:2] = [math.inf, -1e9], [0.0, 1e9]
    for n in (1, 3, 4, 5, 200):
        a, b = level.heights(xs[:n], ys[:n]), plain.heights(xs[:n], ys[:n])
        assert a.shape == b.shape and np.array_equal(a, b) and not np.signbit(a).any()
    assert level.height(12.0, -7.5) == plain.height(12.0, -7.5) == 0.0
    with np.errstate(invalid="ignore"), pytest.raises(IndexError):
        level.heights(np.array([0.0, math.nan, 1.0, 2.0, 3.0]), np.zeros(5))
    z = np.zeros((4, 4))
    z[2, 1] = 0.3
    bump = Heightfield(z, 1.0)
    assert not bump.level and bump.height(-0.5, 0.5) == pytest.approx(0.3)
