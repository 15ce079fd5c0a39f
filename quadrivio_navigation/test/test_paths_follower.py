"""Reference paths and the pure-pursuit follower (closed loop on the simulator core)."""
import math

import numpy as np
import pytest

from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import load_vehicle
from quadrivio_navigation.follower import ABORTED, DONE, FOLLOWING, FollowerParams, PurePursuit
from quadrivio_navigation.paths import (FigureEightParams, SpeedProfileParams, Tracker, distance_to_polyline,
                                        figure_eight, make_path, path_points)


def test_figure_eight_geometry():
    p = FigureEightParams()
    pts = figure_eight(p, (2.0, 3.0, 0.0), ds=0.05)
    assert pts[0] == pytest.approx((3.0, 3.0), abs=1e-9)  # 1 m ahead of the vehicle
    assert pts[-1] == pytest.approx((3.0, 3.0), abs=1e-6)  # back at the crossing
    length = np.sum(np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1])))
    assert length == pytest.approx(math.pi * (18.0 + 12.5), rel=1e-3)
    # First circle on the left (y up to 3 + 18), second on the right (down to 3 - 12.5).
    assert pts[:, 1].max() == pytest.approx(21.0, abs=0.01)
    assert pts[:, 1].min() == pytest.approx(-9.5, abs=0.01)


def test_figure_eight_rotates_with_the_start_pose():
    a = figure_eight(FigureEightParams(), (0.0, 0.0, 0.0))
    b = figure_eight(FigureEightParams(), (0.0, 0.0, math.pi / 2))
    assert b[:, 0] == pytest.approx(-a[:, 1], abs=1e-9)
    assert b[:, 1] == pytest.approx(a[:, 0], abs=1e-9)


def test_path_curvature_and_speed_profile():
    prof = SpeedProfileParams(speed=3.0, max_lateral_accel=1.0, accel=1.0, decel=1.0)
    path = make_path(figure_eight(FigureEightParams()), prof)
    mid1, mid2 = np.argmin(np.abs(path.s - 20.0)), np.argmin(np.abs(path.s - 70.0))
    assert path.kappa[mid1] == pytest.approx(1 / 9.0, rel=0.02)  # left circle
    assert path.kappa[mid2] == pytest.approx(-1 / 6.25, rel=0.02)  # right circle
    assert path.v[mid1] == pytest.approx(math.sqrt(1.0 * 9.0), rel=0.03)  # lateral acceleration limit
    assert path.v[-1] == 0.0
    assert np.all(path.v ** 2 * np.abs(path.kappa) <= 1.0 + 0.05)
    dv = np.diff(path.v ** 2) / (2 * np.diff(path.s))
    assert dv.max() <= 1.0 + 1e-6 and dv.min() >= -1.0 - 1e-6


def test_tracker_follows_a_self_crossing_path():
    path = make_path(figure_eight(FigureEightParams()), SpeedProfileParams())
    tr = Tracker(path, 5.0)
    # Walk along the path: the index never jumps to the other loop at the crossing.
    idx = [tr.nearest(path.x[k], path.y[k] + 0.2) for k in range(0, len(path), 3)]
    assert all(b >= a for a, b in zip(idx, idx[1:]))
    assert tr.cross_track(path.x[50], path.y[50] + 0.0, 50) == pytest.approx(0.0, abs=1e-9)


def test_waypoint_path_and_distance():
    pts = path_points("waypoints", (0.0, 0.0, 0.0), FigureEightParams(), [[10.0, 0.0], [10.0, 5.0]])
    assert pts[-1] == pytest.approx((10.0, 5.0))
    assert distance_to_polyline(pts, 5.0, 1.0) == pytest.approx(1.0, abs=1e-9)
    assert distance_to_polyline(pts, 11.0, 2.0) == pytest.approx(1.0, abs=1e-9)
    with pytest.raises(ValueError, match="unknown path kind"):
        path_points("spiral", (0, 0, 0), FigureEightParams())


def test_follower_stops_when_off_path_or_blind():
    v = load_vehicle()
    path = make_path(figure_eight(FigureEightParams()), SpeedProfileParams())
    pp = PurePursuit(FollowerParams(), path, v)
    assert pp.update(1.0, 0.0, 0.0, 0.0).status == FOLLOWING
    c = pp.update(1.0, 0.0, 0.0, 0.0, pose_age=2.0)
    assert c.status == ABORTED and c.speed == 0.0 and c.brake > 0 and "old" in c.reason
    pp = PurePursuit(FollowerParams(), path, v)
    c = pp.update(1.0, 10.0, 0.0, 1.0)
    assert c.status == ABORTED and "cross-track" in c.reason


def test_follower_drives_the_eight_in_the_simulator():
    """Closed loop on the simulator core with the true pose: the follower itself tracks."""
    from quadrivio_plc import protocol as P
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.simulator import SimParams, Simulator
    from quadrivio_sim.world import quat_to_rpy

    v = load_vehicle()
    sim = Simulator(SimParams(), v, load_actuators(package_file("config", "actuators.yaml")), build_urdf(v))
    path = make_path(figure_eight(FigureEightParams()), SpeedProfileParams(speed=2.5))
    pp = PurePursuit(FollowerParams(), path, v)
    sim.plc.request_mode(P.MODE_AUTO)
    pts = path.xy()
    xte = []
    while sim.t < 90.0:
        if sim.steps % 2 == 0:  # 50 Hz
            pos, orn, vel, _ = sim.world.base_state()
            c = pp.update(pos[0], pos[1], quat_to_rpy(orn)[2], math.hypot(vel[0], vel[1]))
            sim.plc.handle(sim.t, 0, P.Setpoint(P.SOURCE_AUTO, c.speed, c.handlebar, c.brake))
            if c.status == FOLLOWING and c.progress > 0.02:
                xte.append(distance_to_polyline(pts, pos[0], pos[1]))
            if c.status != FOLLOWING:
                break
        sim.step()
    sim.close()
    assert pp.status == DONE, pp.reason
    assert np.sqrt(np.mean(np.square(xte))) < 0.25
    assert max(xte) < 0.8
