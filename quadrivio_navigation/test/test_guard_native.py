"""The roscpp guard's core (include/quadrivio_navigation/guard_core.h) against the Python
reference (guard.py, fields.py, quadrivio_description.attitude, local_layer.dem_ground) on random cases.

The C++ core runs in ``guard_replay`` (test/guard_replay.cpp, built with the workspace): its
configuration is what ``quadrivio_navigation.ros.guard_config.emit`` writes for the C++ node,
then a script of events; each decision (action, speed limit, free distance, fields, nearest
point, setpoint, the stop counters and the reason's text) must match the Python core's.
"""
import io
import math
import subprocess

import numpy as np
import pytest

from quadrivio_config import replace_nested
from quadrivio_description.vehicle import load_vehicle
from quadrivio_description.attitude import Attitude, imu_lever
from quadrivio_navigation.fields import ScanPoints, rep117_ranges, scan_points
from quadrivio_navigation.guard import FAULT, STOP, Guard, GuardParams
from quadrivio_navigation.local_layer import base_on_wheels, dem_ground, wheel_centres
from quadrivio_navigation.ros.guard_config import emit
from quadrivio_description.frames import rpy_matrix
from quadrivio_terrain.terrain import Heightfield
from quadrivio_runtime.workspace import built_executable


class NodeParamsStub:
    base_frame, request_timeout, ground_tolerance = "base_link", 0.25, 0.15
    ground_position_sigmas, ground_tolerance_max, ground_position_sd_min = 2.0, 0.3, 0.5


def _replay_binary():
    path = built_executable("quadrivio_navigation", "guard_replay")
    if path is None:
        pytest.fail("guard_replay not built (make setup builds the workspace)")
    return path


def _config(p, vehicle, hf=None) -> bytes:
    out = io.BytesIO()
    emit(out, p, NodeParamsStub(), vehicle, hf)
    return out.getvalue()


def _run(config: bytes, script) -> list:
    r = subprocess.run([_replay_binary()], input=config + "\n".join(script).encode() + b"\n",
                       stdout=subprocess.PIPE, stderr=subprocess.PIPE, timeout=120)
    assert r.returncode == 0, r.stderr.decode()
    return r.stdout.decode().splitlines()


def _random_events(rng, p, n=400):
    """A random life: states, pitches, scans with points around the path, requests, silences."""
    events = []
    t = 1.0
    v = 0.0
    for _ in range(n):
        t += float(rng.choice([0.02, 0.02, 0.05, 0.1, 0.4]))  # now and then a silence past a timeout
        r = rng.random()
        if r < 0.3:
            v = float(np.clip(v + rng.normal(0, 0.6), -2.0, 4.0)) if rng.random() > 0.1 else 0.0
            events.append(("state", t - float(rng.uniform(0, 0.05)), v, float(rng.uniform(-0.5, 0.5))))
        elif r < 0.4:
            events.append(("pitch", t, float(rng.normal(0, 0.1))))
        elif r < 0.55:  # mostly well inside the test's zone, now and then near its edge or uncertain
            events.append(("pose", t, float(rng.normal(0, 2)), float(rng.normal(0, 2)),
                           float(rng.uniform(-3, 3)), float(abs(rng.normal(0, 0.3)))))
        elif r < 0.75:
            i = int(rng.integers(len(p.scanners)))
            k = int(rng.integers(0, 40))
            pts = np.column_stack([rng.uniform(-8, 12, k), rng.uniform(-3, 3, k)])
            if rng.random() < 0.05:
                events.append(("scanerr", i, t - 0.02, "no transform base_link <- laser on /tf_static"))
            else:
                n_rays = int(rng.integers(k + 1, k + 200))
                invalid = int(rng.integers(0, n_rays - k + 1)) if rng.random() < 0.1 else 0
                events.append(("scan", i, t - float(rng.uniform(0, 0.1)), n_rays, invalid, pts))
        else:
            speed = float(rng.choice([0.0, rng.uniform(-1.5, 4.0)]))
            events.append(("decide", t, speed, float(rng.uniform(-0.6, 0.6)), float(rng.choice([0.0, 0.3]))))
    return events


def _script(events):
    out = []
    for e in events:
        if e[0] == "scan":
            _, i, t, n_rays, invalid, pts = e
            xy = " ".join(f"{x!r} {y!r}" for x, y in pts)
            out.append(f"scan {i} {t!r} {n_rays} {invalid} {len(pts)} {xy}")
        elif e[0] == "ranges":  # a LaserScan's float32 ranges through scanPoints, rays included
            _, i, t, geometry, rr = e
            words = " ".join(repr(float(r)) for r in rr)
            out.append(f"ranges {i} {t!r} " + " ".join(repr(float(g)) for g in geometry) + f" {len(rr)} {words}")
        elif e[0] == "scanerr":
            out.append(f"scanerr {e[1]} {e[2]!r} {e[3]}")
        else:
            out.append(" ".join([e[0]] + [repr(float(x)) for x in e[1:]]))
    return out


def _python(events, p, vehicle, hf=None):
    return _drive(Guard(p, vehicle, None if hf is None else hf.heights), events, p)


def _drive(g, events, p, states=None):
    """The events through guard ``g`` (the Python interface): (decision, setpoint, counters) of
    each request; ``states`` collects ``g.state`` after each vehicle state."""
    out = []
    for e in events:
        if e[0] == "state":
            g.on_state(*e[1:])
            if states is not None:
                states.append(g.state)
        elif e[0] == "pitch":
            g.on_pitch(*e[1:])
        elif e[0] == "pose":
            g.on_pose(*e[1:])
        elif e[0] == "scan":
            _, i, t, n_rays, invalid, pts = e
            g.on_scan(p.scanners[i].topic, t, ScanPoints(pts, n_rays, invalid, 0))
        elif e[0] == "ranges":
            _, i, t, (amin, inc, rmin, rmax, mx, my, myaw, max_range), rr = e
            rr = rep117_ranges(rr, rmax, p.scanners[i].no_return)  # as guard_node.cpp and guard_replay
            g.on_scan(p.scanners[i].topic, t, scan_points(rr, amin, inc, rmin, rmax, (mx, my, myaw), max_range))
        elif e[0] == "scanerr":
            g.on_scan(p.scanners[e[1]].topic, e[2], None, e[3])
        else:
            _, now, speed, h, brake = e
            d = g.decide(now, speed, h)
            sp = g.command(d, speed, h, brake)
            out.append((d, sp, g.protective_stops, g.fault_stops, g.zone_stops))
    return out


def _compare(py, cpp):
    assert len(py) == len(cpp)
    actions = set()
    for k, ((d, sp, ps, fs, zs), line) in enumerate(zip(py, cpp)):
        head, field, scanner, reason = line.split("|", 3)
        v = head.split()[1:]
        where = f"decision {k}: python {d} / c++ {line}"
        assert int(v[0]) == d.action, where
        actions.add(d.action)
        nums = [float(x) for x in v[1:6]] + [float(x) for x in v[11:15]]
        ref = [d.limit, d.free, d.protective, d.protective_request, d.warning, d.slope, sp.speed, sp.handlebar,
               sp.brake]
        for a, b in zip(nums, ref):
            assert (a == b) or abs(a - b) <= 1e-9 * max(1.0, abs(b)), where
        assert bool(int(v[6])) == (d.nearest is not None), where
        if d.nearest is not None:
            assert float(v[7]) == pytest.approx(d.nearest[0], abs=1e-12), where
            assert float(v[8]) == pytest.approx(d.nearest[1], abs=1e-12), where
        assert int(v[10]) == d.direction, where
        ss = float(v[9])
        assert (math.isnan(ss) and math.isnan(d.scan_stamp)) or ss == d.scan_stamp, where
        assert (int(v[15]), int(v[16]), int(v[17])) == (ps, fs, zs), where
        assert (field, scanner, reason) == (d.field, d.scanner, d.reason), where
    return actions


@pytest.mark.parametrize("seed", range(7))
def test_decisions_match_the_python_core(seed):
    vehicle = load_vehicle()
    p = GuardParams()
    if seed == 6:  # one laser, forward: reversing is blind (a fail-safe stop in both)
        p = replace_nested(p, {"scanners": [{"topic": "scan/front", "frame": "laser_front", "covers": "forward"}]})
    if seed % 3 == 1:  # other values than ours: a faster brake, a longer margin, one scanner covering both ways
        p = replace_nested(p, {"brake_decel": 5.0, "margin": 0.6, "warning_margin": 1.5, "creep_margin": 0.7,
                               "clear_time": 0.3, "scanners": [{"topic": "scan/all", "frame": "laser", "covers": "both"}]})
    if seed % 3 == 2:  # an operating zone
        p = replace_nested(p, {"zone": [[-6.0, -6.0], [9.0, -5.0], [7.0, 8.0], [-5.0, 6.0]], "max_position_sd": 0.8})
    rng = np.random.default_rng(seed)
    hf = None
    if seed % 2 == 1:  # a DEM: the braking slope is its grade ahead (a steep, rough one, not ours)
        hf = Heightfield(np.cumsum(np.random.default_rng(100 + seed).normal(0.01, 0.03, (61, 81)), axis=1), 0.25)
    events = _random_events(rng, p)
    cpp = _run(_config(p, vehicle, hf), _script(events))
    py = _python(events, p, vehicle, hf)
    actions = _compare(py, cpp)
    assert len(actions) >= 3, f"the random cases reached only actions {actions}"
    if hf is not None:
        slopes = {round(d.slope, 6) for d, *_ in py if d.direction != 0} - {0.0, round(p.slope_unknown, 6)}
        assert len(slopes) >= 2, "the DEM gave the fields hardly any slope: the comparison tests little"


def test_attitude_matches_the_python_filter():
    vehicle = load_vehicle()
    rng = np.random.default_rng(7)
    a = Attitude(GuardParams().slope_tau, lever=imu_lever(vehicle))
    script, ref = [], []
    t = 0.0
    for k in range(600):
        t += 0.01
        if k % 2 == 0:
            v = float(2.0 + np.sin(t) + (rng.normal(0, 3) if k % 97 == 0 else 0.0))  # now and then a wheel's jump
            a.add_speed(t, v)
            script.append(f"attitude_speed {t!r} {v!r}")
        f = (float(rng.normal(0.5, 1)), float(rng.normal(0, 1)), float(9.81 + rng.normal(0, 0.3)))
        w = tuple(float(x) for x in rng.normal(0, 0.3, 3))
        a.add_imu(t, f, w)
        ref.append((a.roll, a.pitch))
        script.append("attitude_imu " + " ".join(repr(x) for x in (t,) + f + w))
    out = _run(_config(GuardParams(), vehicle), script)
    got = np.array([[float(x) for x in line.split()[1:]] for line in out])
    assert np.allclose(got, np.array(ref), atol=1e-12)


def test_dem_ground_matches_the_python_test():
    vehicle = load_vehicle()
    rng = np.random.default_rng(3)
    z = np.cumsum(rng.normal(0, 0.05, (41, 61)), axis=1)  # a rough grid, not ours
    hf = Heightfield(z, 0.5)
    script, ref = [], []
    for _ in range(20):
        pos = (float(rng.uniform(-10, 10)), float(rng.uniform(-8, 8)), float(rng.uniform(0, 1.5)))
        rpy = tuple(float(x) for x in rng.normal(0, [0.1, 0.1, 2.0]))
        n = 181
        ranges = rng.uniform(0.0, 25.0, n)
        ranges[rng.random(n) < 0.1] = math.nan
        ranges[rng.random(n) < 0.05] = math.inf
        amin, inc = -math.pi / 2, math.pi / (n - 1)
        R = np.array(rpy_matrix(rpy))
        per_m, slack, cap = (float(rng.choice([0.0, 0.02])), float(rng.choice([0.0, rng.uniform(0, 2)])),
                             float(rng.choice([math.inf, 0.35])))
        ground = dem_ground(hf.heights, np.array(pos), R, 0.3, per_m, slack, cap)
        r = ranges.astype(np.float32).astype(float)  # the scan's float32
        hit = np.isfinite(r) & (r >= 0.1) & (r <= min(30.0, 20.0))
        expect = np.zeros(n, dtype=bool)
        bearings = amin + inc * np.arange(n)
        expect[hit] = ground(bearings[hit], r[hit])
        ref.append(expect)
        script.append("ground " + " ".join(repr(x) for x in pos + rpy + (amin, inc, 0.1, 30.0, 20.0, 0.3, per_m, slack,
                                                                         cap)) +
                      f" {n} " + " ".join(repr(float(x)) for x in r))
    out = _run(_config(GuardParams(), vehicle, hf), script)
    got = [np.array([bool(int(x)) for x in line.split()[1:]]) for line in out]
    some = 0
    for g, e in zip(got, ref):
        assert np.array_equal(g, e)
        some += int(e.sum())
    assert some > 20, "the random scans hardly touched the ground: the comparison tests little"


def test_base_on_wheels_matches_the_python_model():
    """base_link's height on its wheels and the gradient under them (local_layer.base_on_wheels)
    on a rough grid, not ours: the same to the rounding."""
    vehicle = load_vehicle()
    rng = np.random.default_rng(5)
    z = np.cumsum(rng.normal(0, 0.05, (41, 61)), axis=1)
    hf = Heightfield(z, 0.5)
    wheels = wheel_centres(vehicle)
    script, ref = [], []
    for _ in range(30):
        x, y = float(rng.uniform(-12, 12)), float(rng.uniform(-8, 8))
        rpy = tuple(float(a) for a in rng.normal(0, [0.15, 0.15, 2.0]))
        ref.append(base_on_wheels(hf.heights, x, y, np.array(rpy_matrix(rpy)), vehicle.wheel_radius, wheels))
        script.append("base " + " ".join(repr(a) for a in (x, y) + rpy))
    out = _run(_config(GuardParams(), vehicle, hf), script)
    got = np.array([[float(a) for a in line.split()[1:]] for line in out])
    assert np.allclose(got, np.array(ref), rtol=0, atol=1e-12)
    assert np.ptp(got[:, 1]) > 0.05, "the gradients hardly vary: the comparison tests little"


@pytest.mark.parametrize("seed", range(3))
def test_moving_obstacles_match_the_python_core(seed):
    """A drive past trees with people and a tractor crossing ahead: the tracks (tracks.py, the
    C++ MotionTracker), what the scans saw through, and the decisions on where they will be are
    the same, in the replay and through NativeGuard. Thick trunks beside the lane make
    centroids travel that the rays' test must refuse; the tractor is found by its leading
    corner (an end of its cluster), and a parked machine's ends must not move."""
    from test_tracks import ranges
    from quadrivio_navigation import tracks
    vehicle = load_vehicle()
    p = GuardParams()
    rng = np.random.default_rng(seed)
    trees = [(x, y, 0.15) for x in np.arange(4.0, 40.0, 1.5) for y in (-2.5, 2.5)]
    trees += [(x, y, 0.57) for x in np.arange(5.0, 40.0, 6.0) for y in (-1.6, 1.6)]
    people = [(float(rng.uniform(9, 20)), float(rng.choice([-1, 1])) * float(rng.uniform(0.8, 1.8)),
               float(rng.uniform(0.25, 0.35)), float(rng.uniform(0.0, 3.0))) for _ in range(3)]  # x, speed, r, start
    people[0] = (float(rng.uniform(14, 16)), 1.4, 0.3, float(rng.uniform(1.5, 2.0)))  # one steps out ~8 m ahead
    other = np.random.default_rng(100 + seed)  # (the people's draws as they were)
    tractor = (float(other.uniform(-6.0, 0.0)), float(other.uniform(1.0, 3.0)))  # x, start: along y = 9 at 4 m/s
    events, x, y, yaw, v = [], 0.0, 0.0, 0.0, 2.5
    for k in range(400):
        t = 1.0 + 0.02 * k
        h = 0.015 * math.sin(0.7 * t)  # weaving gently along the lane
        v = max(0.0, v + float(rng.normal(0, 0.05)))
        events.append(("state", t, v, h))
        if k % 5 == 0:
            circles = list(trees)
            for px, u, r, t0 in people:
                y0 = -2.8 if u > 0 else 2.8  # from behind a tree row
                circles.append((px, y0 + u * max(0.0, t - 1.0 - t0), r))
            fov = math.radians(270.0)
            tx = tractor[0] + 4.0 * max(0.0, t - tractor[1])
            boxes = [(tx, 9.0, 0.0, 4.0, 2.0), (30.0, -4.0, 0.3, 4.0, 2.0)]  # crossing 9 m to the left; parked
            rr = ranges((x, y, yaw), circles, mount=(1.7, 0.0), fov=fov, rng=rng, noise=0.01, boxes=boxes)
            # dropouts (NaN) and returns beyond range_max: unknown rays (-inf, something at the
            # laser's window, is an obstacle at range_min itself, and would stop the vehicle)
            odd = rng.random(len(rr)) < 0.02
            rr[odd] = rng.choice(np.array([np.nan, 35.0], dtype=np.float32), int(odd.sum()))
            events.append(("ranges", 0, t - 0.03, (-fov / 2, fov / 540, 0.05, 30.0, 1.7, 0.0, 0.0, 20.0), rr))
            events.append(("scan", 1, t - 0.03, 541, 0, np.zeros((0, 2))))
        events.append(("decide", t, 3.0, h, 0.0))
        w = v * math.tan(vehicle.steering.ratio * h) / vehicle.wheelbase
        x, y, yaw = x + v * math.cos(yaw) * 0.02, y + v * math.sin(yaw) * 0.02, yaw + w * 0.02
    cpp = _run(_config(p, vehicle), _script(events))
    refused, ends = [], []
    moved_through, end_moves = tracks.MotionTracker._moved_through, tracks.MotionTracker._end_moves

    def counted(self, k, i):
        out = moved_through(self, k, i)
        refused.append(not out)
        return out

    def ended(self, k, end):
        out = end_moves(self, k, end)
        ends.append(out is not None)
        return out

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(tracks.MotionTracker, "_moved_through", counted)
        mp.setattr(tracks.MotionTracker, "_end_moves", ended)
        py = _python(events, p, vehicle)
    _compare(py, cpp)
    native, _ = _wrapped(events, p, vehicle)
    assert [(d.action, d.reason, d.limit, d.nearest) for d, *_ in native] == \
        [(d.action, d.reason, d.limit, d.nearest) for d, *_ in py]
    moving = [d.reason for d, *_ in py if "moving obstacle" in d.reason]
    assert moving, "no decision acted on a moving obstacle: the comparison tests little"
    assert any(refused) and not all(refused), "the rays' test never decided: the comparison tests little"
    assert any(ends), "no end of a cluster moved: the comparison tests little"


def test_what_a_scan_saw_through_matches_the_python_core():
    """tracks.seen_through and guard_core.h's seenThrough on random lasers (any yaw, upside
    down, tilted, angles turning either way, all around or not), unknown rays, and points near
    the returns, beyond the field of view and across the angles' wrap: the same counts."""
    from quadrivio_navigation.fields import Rays
    from quadrivio_navigation.tracks import SeenScan, TrackParams, seen_through
    rng = np.random.default_rng(17)
    lines, want, nonzero = [], [], 0
    for case in range(400):
        n = int(rng.integers(8, 400))
        inc = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 1.0) * 2.0 * math.pi / n)
        if rng.random() < 0.5:  # a field of view short of all around
            inc *= float(rng.uniform(0.3, 0.95))
        amin = float(rng.uniform(-math.pi, math.pi))
        kind = rng.integers(3)
        yaw = float(rng.uniform(-math.pi, math.pi))
        c, s = math.cos(yaw), math.sin(yaw)
        m = [(c, -s, s, c), (c, s, s, -c), (c * 0.8, -s, s * 0.8, c)][kind]  # yawed, upside down, tilted
        free = np.maximum(float(rng.uniform(3.0, 12.0)) + rng.normal(0.0, 0.3, n), 0.0)
        few = rng.random(n) < 0.05
        free[few] = rng.choice([np.nan, 1.0, 2.5], int(few.sum()))  # unknown rays and near returns
        if rng.random() < 0.2:  # a dropout: a run of unknown rays
            j = int(rng.integers(n))
            free[j:j + int(rng.integers(2, 30))] = np.nan
        vyaw = float(rng.uniform(-math.pi, math.pi))
        sc = SeenScan(0.0, float(rng.normal(0, 5)), float(rng.normal(0, 5)), math.cos(vyaw), math.sin(vyaw),
                      Rays((0.0, 0.0), m, amin, inc, free))
        p = TrackParams(seen_margin=float(rng.uniform(0.0, 0.3)), seen_angle=float(rng.uniform(0.0, 0.05)))
        pts = np.column_stack([sc.ox + rng.uniform(-9, 9, 6), sc.oy + rng.uniform(-9, 9, 6)])
        want.append(seen_through(sc, pts, p))
        nonzero += want[-1] > 0
        nums = [sc.ox, sc.oy, sc.c, sc.s, *m, amin, inc, p.seen_margin, p.seen_angle, n, *free, len(pts), *pts.ravel()]
        lines.append("seen " + " ".join(repr(float(v)) if not isinstance(v, int) else str(v) for v in nums))
    out = _run(_config(GuardParams(), load_vehicle()), lines)
    assert [int(line.split()[1]) for line in out] == want
    assert 50 < nonzero < 350, "the random cases are all or nothing: the comparison tests little"


@pytest.mark.parametrize("edit, error", [
    (lambda t: t.replace("param track_min_obs 3.0", "param track_min_obs 2.5"),
     "parameter 'track_min_obs' must be a whole number"),
    (lambda t: "\n".join(ln for ln in t.splitlines() if not ln.startswith("param track_max_points ")) + "\n",
     "no value for parameter 'track_max_points'"),
    (lambda t: t.replace("param track_coast ", "param track_coasting "), "unknown parameter 'track_coasting'"),
    (lambda t: t.replace("laser_front forward inf", "laser_front forward 0"),
     "scanner scan/front: no_return '0': expected one of inf, zero, beyond_max"),
])
def test_the_cpp_reader_names_a_bad_configuration(edit, error):
    """The roscpp guard's reader (guard_core.h readConfig): the tracker's whole-number keys
    refuse a fraction, and a missing or unknown key is named, not defaulted."""
    text = _config(GuardParams(), load_vehicle()).decode()
    assert "param track_min_obs 3.0\n" in text and "param track_coast " in text
    r = subprocess.run([_replay_binary()], input=edit(text).encode(), stdout=subprocess.PIPE,
                       stderr=subprocess.PIPE, timeout=60)
    assert r.returncode == 1
    assert error in r.stderr.decode()


def _wrapped(events, p, vehicle, hf=None):
    """The events through NativeGuard (the core in this process), and its state after each vehicle state."""
    from quadrivio_navigation.guard_native import NativeGuard

    states = []
    return _drive(NativeGuard(p, vehicle, hf, NodeParamsStub()), events, p, states), states


@pytest.mark.parametrize("seed", range(5))
def test_the_wrapper_decides_as_the_python_guard(seed):
    """NativeGuard (guard_native.py: the C++ core through ctypes, what the closed loop in one
    process runs) on the random lives of the tests above: every decision's action, numbers,
    nearest point, texts and counters are the Python guard's, its state the last one given."""
    vehicle = load_vehicle()
    p = GuardParams()
    if seed == 1:
        p = replace_nested(p, {"brake_decel": 5.0, "margin": 0.6, "warning_margin": 1.5, "creep_margin": 0.7,
                               "clear_time": 0.3, "scanners": [{"topic": "scan/all", "frame": "laser", "covers": "both"}]})
    if seed == 2:
        p = replace_nested(p, {"zone": [[-6.0, -6.0], [9.0, -5.0], [7.0, 8.0], [-5.0, 6.0]], "max_position_sd": 0.8})
    if seed == 4:  # one laser, forward only
        p = replace_nested(p, {"scanners": [{"topic": "scan/front", "frame": "laser_front", "covers": "forward"}]})
    hf = Heightfield(np.cumsum(np.random.default_rng(200 + seed).normal(0.01, 0.03, (61, 81)), axis=1), 0.25) \
        if seed % 2 else None
    events = _random_events(np.random.default_rng(50 + seed), p)
    py = _python(events, p, vehicle, hf)
    native, states = _wrapped(events, p, vehicle, hf)
    assert len(py) == len(native) > 50
    actions = set()
    for k, ((d, sp, *counts), (dn, spn, *counts_n)) in enumerate(zip(py, native)):
        where = f"decision {k}: python {d} / native {dn}"
        assert (dn.action, dn.direction, dn.field, dn.scanner, dn.reason) == \
            (d.action, d.direction, d.field, d.scanner, d.reason), where
        for a, b in ((dn.limit, d.limit), (dn.free, d.free), (dn.protective, d.protective),
                     (dn.protective_request, d.protective_request), (dn.warning, d.warning), (dn.slope, d.slope),
                     (spn.speed, sp.speed), (spn.handlebar, sp.handlebar), (spn.brake, sp.brake)):
            assert a == b or abs(a - b) <= 1e-9 * max(1.0, abs(b)), where
        assert (dn.nearest is None) == (d.nearest is None), where
        if d.nearest is not None:
            assert dn.nearest == pytest.approx(d.nearest, abs=1e-12), where
        assert (math.isnan(dn.scan_stamp) and math.isnan(d.scan_stamp)) or dn.scan_stamp == d.scan_stamp, where
        assert counts_n == counts, where
        actions.add(d.action)
    assert len(actions) >= 3, f"the random cases reached only actions {actions}"
    given = [e for e in events if e[0] == "state"]
    assert [s[1:] for s in states] == [(e[2], e[3]) for e in given]


def test_the_wrapper_names_a_bad_configuration_and_a_missing_library(monkeypatch):
    from quadrivio_navigation import guard_native
    from quadrivio_navigation.ros import guard_config

    def unknown_key(out, *args):  # what a configuration writer out of step with the core would send
        buf = io.BytesIO()
        emit(buf, *args)
        out.write(b"param track_coasting 1.0\n" + buf.getvalue())
    monkeypatch.setattr(guard_config, "emit", unknown_key)
    with pytest.raises(ValueError, match="refused its configuration: .*unknown parameter 'track_coasting'"):
        guard_native.NativeGuard(GuardParams(), load_vehicle(), None, NodeParamsStub())
    monkeypatch.setattr(guard_native, "_LIB", None)
    monkeypatch.setattr(guard_native, "find_library", lambda name: (_ for _ in ()).throw(FileNotFoundError(name)))
    with pytest.raises(guard_native.GuardUnavailable, match="make setup"):
        guard_native.load_library()


def test_the_cores_defaults_are_guard_yamls():
    """guard.yaml is held to GuardParams by test_config_files; here the defaults written twice
    more are held to GuardParams: the Python tracker's TrackParams and the C++ core's Params,
    TrackParams and node keys (every numeric key, both ways)."""
    from dataclasses import fields
    from quadrivio_navigation.guard import GuardNodeParams
    from quadrivio_navigation.guard_native import native_defaults
    from quadrivio_navigation.tracks import TrackParams

    g, node = GuardParams(), GuardNodeParams()
    assert TrackParams() == g.tracks()
    native = native_defaults()
    numeric = {f.name: getattr(g, f.name) for f in fields(g)
               if isinstance(getattr(g, f.name), (int, float)) and not isinstance(getattr(g, f.name), bool)}
    core = {k: v for k, v in native.items() if not k.startswith("node_")}
    assert sorted(core) == sorted(numeric), "keys the C++ core and GuardParams do not share"
    differ = {k: (core[k], numeric[k]) for k in core if core[k] != numeric[k]}
    assert not differ, f"C++ default != GuardParams default (C++, Python): {differ}"
    node_keys = {k[len("node_"):]: v for k, v in native.items() if k.startswith("node_")}
    assert node_keys, "the C++ core reports no node keys"
    differ = {k: (v, getattr(node, k)) for k, v in node_keys.items() if v != getattr(node, k)}
    assert not differ, f"C++ default != GuardNodeParams default (C++, Python): {differ}"


@pytest.mark.parametrize("no_return", ["zero", "beyond_max"])
def test_a_driver_older_than_rep117_guards_as_one_that_follows_it(no_return):
    """A laser whose driver reports a ray that saw nothing as 0.0 (LMS1xx, older sick_tim) or
    beyond range_max (pointcloud_to_laserscan without use_inf), driving at a post among a few
    in an open field: with the scanner's ``no_return`` saying so, every decision is the one on
    the same scans in REP 117's terms, in the Python guard, the C++ replay and NativeGuard.
    Under REP 117's ``no_return`` the same scans blind it: a FAULT whose reason says what the
    rays read and which ``no_return`` would take them for nothing seen, word for word in both
    cores."""
    from test_tracks import ranges
    vehicle = load_vehicle()
    rng = np.random.default_rng(3)
    posts = [(float(rng.uniform(5, 40)), float(rng.choice([-1, 1]) * rng.uniform(4, 15)), 0.1) for _ in range(8)]
    posts.append((12.0, 0.3, 0.1))  # on the way
    fov, rmin, rmax = math.radians(270.0), 0.05, 30.0
    rep117, legacy = [], []
    x, v = 0.0, 2.5
    for k in range(250):
        t = 1.0 + 0.02 * k
        for ev in (rep117, legacy):
            ev.append(("state", t, v, 0.0))
        if k % 5 == 0:
            rr = ranges((x, 0.0, 0.0), posts, mount=(1.7, 0.0), fov=fov, rng=rng, noise=0.01)
            geometry = (-fov / 2, fov / 540, rmin, rmax, 1.7, 0.0, 0.0, 20.0)
            rep117.append(("ranges", 0, t - 0.03, geometry, rr))
            nothing = np.float32(0.0 if no_return == "zero" else rmax + 1.0)  # as the driver reports no echo
            legacy.append(("ranges", 0, t - 0.03, geometry, np.where(np.isposinf(rr), nothing, rr)))
            for ev in (rep117, legacy):
                ev.append(("scan", 1, t - 0.03, 541, 0, np.zeros((0, 2))))
        for ev in (rep117, legacy):
            ev.append(("decide", t, 2.5, 0.0, 0.0))
        v = max(0.0, v - 3.5 * 0.02) if k > 170 else v  # it brakes, as told or not: the stop's hold too
        x += v * 0.02
    told = replace_nested(GuardParams(), {"scanners": [
        {"topic": "scan/front", "frame": "laser_front", "covers": "forward", "no_return": no_return},
        {"topic": "scan/rear", "frame": "laser_rear", "covers": "reverse"}]})
    ref = _python(rep117, GuardParams(), vehicle)
    key = [(d.action, d.reason, d.limit, d.nearest) for d, *_ in ref]
    acts = {k[0] for k in key}
    assert STOP in acts and len(acts) >= 3, f"only actions {acts}: the comparison tests little"
    for p in (told, GuardParams()):
        py = _python(legacy, p, vehicle)
        _compare(py, _run(_config(p, vehicle), _script(legacy)))
        native, _ = _wrapped(legacy, p, vehicle)
        assert [(d.action, d.reason, d.limit, d.nearest) for d, *_ in native] == \
            [(d.action, d.reason, d.limit, d.nearest) for d, *_ in py]
        if p is told:
            assert [(d.action, d.reason, d.limit, d.nearest) for d, *_ in py] == key
        else:
            read = "read 0 m" if no_return == "zero" else "beyond range_max"
            reasons = {d.reason for d, *_ in py}
            assert {d.action for d, *_ in py} == {FAULT}
            assert all(
                r.startswith("scan/front blinded: ") and read in r and r.endswith(f"no_return: {no_return}")
                for r in reasons), reasons
