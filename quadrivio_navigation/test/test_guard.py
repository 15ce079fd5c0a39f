"""The obstacle guard's fields against hand calculations, REP 117, and its stop/hold/release
cycle and fail-safe (quadrivio_navigation.fields, quadrivio_navigation.guard)."""
import math

import numpy as np
import pytest

from quadrivio_config import ConfigError, from_mapping
from quadrivio_description.vehicle import GRAVITY, load_vehicle
from quadrivio_navigation.costmap import Footprint
from quadrivio_navigation.fields import (ScanError, allowed_speed, check_scan, effective_decel, free_distance,
                                         scan_points, stopping_distance, sweep)
from quadrivio_navigation.guard import (CLEAR, FAULT, HOLD, SLOW, STOP, Guard, GuardParams, check_zone,
                                        distance_to_edges, points_in_polygon)


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


FP = Footprint(front=1.8, rear=0.5, left=0.7, right=0.7)


# ------------------------------------------------------------------ fields
def test_stopping_distance_and_its_inverse_by_hand():
    # v t + v^2 / 2a: 2 m/s, 0.25 s, 3.5 m/s^2 -> 0.5 + 4 / 7
    assert stopping_distance(2.0, 0.25, 3.5) == pytest.approx(0.5 + 4.0 / 7.0)
    assert stopping_distance(-2.0, 0.25, 3.5) == pytest.approx(0.5 + 4.0 / 7.0)  # reverse: the same
    for v in (0.1, 0.7, 2.0, 3.0, 5.5):
        d = stopping_distance(v, 0.3, 1.2)
        assert allowed_speed(d, 0.3, 1.2) == pytest.approx(v, rel=1e-9)
    assert allowed_speed(0.0, 0.3, 1.2) == 0.0 and allowed_speed(-1.0, 0.3, 1.2) == 0.0
    assert allowed_speed(math.inf, 0.3, 1.2) == math.inf


def test_slope_shortens_the_braking():
    # 10 deg downhill: a - g sin(10 deg); uphill brakes harder; floor when the brake cannot hold
    assert effective_decel(3.5, math.radians(10)) == pytest.approx(3.5 - GRAVITY * math.sin(math.radians(10)))
    assert effective_decel(3.5, -math.radians(10)) > 3.5
    assert effective_decel(3.5, math.radians(30)) == pytest.approx(0.3)
    flat = stopping_distance(2.0, 0.2, effective_decel(3.5, 0.0))
    down = stopping_distance(2.0, 0.2, effective_decel(3.5, math.radians(10)))
    assert down == pytest.approx(0.4 + 4.0 / (2 * (3.5 - GRAVITY * math.sin(math.radians(10)))))
    assert down > 1.5 * flat - 0.4


def test_straight_sweep_free_distance():
    poses = sweep(1, 0.0, 0.0, 0.8, 2.0, 5.0, 0.05, 1.25)
    assert np.allclose(poses[:, 1], 0.0) and np.allclose(poses[:, 2], 0.0)
    assert poses[-1, 0] == pytest.approx(5.0, abs=0.05)
    # a point 2.0 m ahead of the front edge, on the centre line: free 2.0 m (one step conservative)
    f = free_distance(FP, poses, np.array([[FP.front + 2.0, 0.0]]), 0.05)
    assert 1.9 <= f.distance <= 2.0
    # beside the path (0.05 m outside the swept band): never touched
    f = free_distance(FP, poses, np.array([[3.0, FP.left + 0.05], [3.0, -FP.right - 0.05]]), 0.05)
    assert f.distance == math.inf
    # inside the footprint already: 0
    assert free_distance(FP, poses, np.array([[1.0, 0.2]]), 0.05).distance == 0.0


def test_turning_sweep_follows_the_arc(vehicle):
    h = 0.3
    L = vehicle.wheelbase
    R = L / math.tan(h)  # rear axle centre's turning radius
    poses = sweep(1, h, h, 0.8, 2.0, 4.0, 0.02, L)
    # the rear axle stays on the circle about (0, R)
    assert np.allclose(np.hypot(poses[:, 0], poses[:, 1] - R), R, atol=1e-3)
    assert poses[-1, 2] == pytest.approx(4.0 / R, abs=0.01)
    # the front edge's centre after turning phi: a point 1 cm ahead of it is reached after s = R phi
    phi = 0.6
    bx, by = FP.front, 0.0
    c, s = math.cos(phi), math.sin(phi)
    px, py = c * bx - s * (by - R), R + s * bx + c * (by - R)
    px, py = px + 0.01 * c, py + 0.01 * s
    f = free_distance(FP, poses, np.array([[px, py]]), 0.02)
    assert f.distance == pytest.approx(R * phi, abs=0.05)
    # the same point with the handlebar straight: missed (it lies off to the left)
    straight = sweep(1, 0.0, 0.0, 0.8, 2.0, 4.0, 0.02, L)
    assert free_distance(FP, straight, np.array([[px, py]]), 0.02).distance == math.inf


def test_handlebar_turns_at_the_servo_rate(vehicle):
    # from straight toward 0.4 rad at 0.8 rad/s at 2 m/s: straight at first, 0.4 rad after 1 m
    poses = sweep(1, 0.0, 0.4, 0.8, 2.0, 3.0, 0.01, vehicle.wheelbase)
    heading_rate = np.diff(poses[:, 2]) / 0.01
    assert heading_rate[0] == pytest.approx(0.0, abs=0.01)
    k_full = math.tan(0.4) / vehicle.wheelbase
    assert heading_rate[150] == pytest.approx(k_full, rel=0.02)  # 1.5 m along, past the 1 m of the turn
    assert heading_rate[50] == pytest.approx(math.tan(0.2) / vehicle.wheelbase, rel=0.05)  # half-way at 0.5 m


def test_reverse_sweep_goes_backwards(vehicle):
    poses = sweep(-1, 0.0, 0.0, 0.8, 1.0, 3.0, 0.05, vehicle.wheelbase)
    assert poses[-1, 0] == pytest.approx(-3.0, abs=0.05)
    behind = np.array([[-FP.rear - 1.5, 0.0]])
    assert 1.4 <= free_distance(FP, poses, behind, 0.05).distance <= 1.5
    ahead = sweep(1, 0.0, 0.0, 0.8, 1.0, 3.0, 0.05, vehicle.wheelbase)
    assert free_distance(FP, ahead, behind, 0.05).distance == math.inf
    # reversing with the handlebar left: back along the same circle about the turning centre
    # (0, R) on the left, so the heading turns right (negative yaw rate) and the axle goes left
    poses = sweep(-1, 0.3, 0.3, 0.8, 1.0, 2.0, 0.02, vehicle.wheelbase)
    R = vehicle.wheelbase / math.tan(0.3)
    assert np.allclose(np.hypot(poses[:, 0], poses[:, 1] - R), R, atol=1e-3)
    assert poses[-1, 2] == pytest.approx(-2.0 / R, abs=0.02) and poses[-1, 0] < 0.0 < poses[-1, 1]


# ---------------------------------------------------------------- REP 117
def test_rep117_ranges():
    ranges = [math.nan, math.inf, -math.inf, 0.05, 40.0, 5.0]
    inc = 0.1
    sp = scan_points(ranges, -0.25, inc, 0.1, 30.0, (1.0, 0.0, 0.0))
    assert sp.n_rays == 6
    assert sp.n_invalid == 3  # NaN, and the finite ranges outside [0.1, 30]
    assert sp.n_too_close == 1
    assert len(sp.xy) == 2  # -inf (at range_min) and 5.0; +inf is nothing
    a_close, a_far = -0.25 + 2 * inc, -0.25 + 5 * inc
    assert sp.xy[0] == pytest.approx([1.0 + 0.1 * math.cos(a_close), 0.1 * math.sin(a_close)])
    assert sp.xy[1] == pytest.approx([1.0 + 5.0 * math.cos(a_far), 5.0 * math.sin(a_far)])
    # how far each ray saw empty space (the tracker's seen-through test): the return's range,
    # -inf up to range_min, +inf up to range_max, nothing known (NaN) of NaN and the ranges
    # outside the limits
    assert np.array_equal(sp.rays.free, [math.nan, 30.0, 0.1, math.nan, math.nan, 5.0], equal_nan=True)
    assert sp.rays.origin == (1.0, 0.0) and sp.rays.m == (1.0, -0.0, 0.0, 1.0)
    # a laser mounted backwards (yaw pi): a return ahead of it is behind the vehicle
    sp = scan_points([2.0], 0.0, 0.1, 0.1, 30.0, (-0.4, 0.0, math.pi))
    assert sp.xy[0] == pytest.approx([-2.4, 0.0])
    # mounted upside down (roll pi): its angles turn the other way
    flip = np.diag([1.0, -1.0, -1.0])
    sp = scan_points([2.0], 0.5, 0.1, 0.1, 30.0, (1.0, 0.0, 0.0), rotation=flip)
    assert sp.xy[0] == pytest.approx([1.0 + 2.0 * math.cos(0.5), -2.0 * math.sin(0.5)])


def test_drivers_older_than_rep117_are_read_by_their_no_return():
    """A driver reports a ray that saw nothing as REP 117's +inf, as 0.0 (LMS1xx without
    publish_min_range_as_inf, older sick_tim) or beyond range_max (pointcloud_to_laserscan
    without use_inf: range_max + 1). The scanner's no_return turns exactly that into +inf
    and nothing else: a Hokuyo's error codes below range_min stay invalid, -inf and NaN stay.
    (What the simulator's adapters publish for each reads back as it was: test_closed_loop.)"""
    from quadrivio_navigation.fields import blinded_reason, rep117_ranges

    raw = [0.0, 0.004, 31.0, 30.0, 5.0, -math.inf, math.nan, math.inf]
    want = {"inf": raw,
            "zero": [math.inf, 0.004, 31.0, 30.0, 5.0, -math.inf, math.nan, math.inf],
            "beyond_max": [0.0, 0.004, math.inf, 30.0, 5.0, -math.inf, math.nan, math.inf]}
    for mode, out in want.items():
        assert np.array_equal(rep117_ranges(raw, 30.0, mode), out, equal_nan=True), mode
    with pytest.raises(ValueError, match="no_return 'nan': expected one of inf, zero, beyond_max"):
        rep117_ranges(raw, 30.0, "nan")
    with pytest.raises(ConfigError, match="no_return"):
        from_mapping(GuardParams, {"scanners": [{"topic": "scan", "frame": "laser", "no_return": "0"}]})
    # the invalid rays that read 0.0 or beyond range_max are counted, and the blinded reason says so
    sp = scan_points(raw, -0.4, 0.1, 0.1, 30.0, (1.0, 0.0, 0.0))
    assert (sp.n_invalid, sp.n_zero, sp.n_beyond) == (4, 1, 1)  # 0.0, 0.004, 31, NaN
    assert blinded_reason("scan/front", 8, 4, 1, 1) == "scan/front blinded: 50 % of its rays invalid"
    assert blinded_reason("scan/front", 10, 8, 7, 0) == (
        "scan/front blinded: 80 % of its rays invalid, 70 % read 0 m: a driver that reports no echo so needs the "
        "scanner's no_return: zero")
    assert blinded_reason("scan/rear", 10, 6, 0, 4).endswith("40 % beyond range_max: a driver that reports no "
                                                            "echo so needs the scanner's no_return: beyond_max")


def test_what_the_guard_logs():
    """A change of action (not between CLEAR and SLOW, not into the first decision), and a
    FAULT that lasts, again every FAULT_RELOG s while its reason is not the one logged."""
    from quadrivio_navigation.guard import FAULT_RELOG, DecisionLog

    log = DecisionLog()
    seq = [(0.0, FAULT, None, "no scan yet from scan/front"),  # the first: not logged
           (0.1, FAULT, FAULT, "no scan yet from scan/front"),
           (1.0, CLEAR, FAULT, ""), (2.0, SLOW, CLEAR, "obstacle"), (2.5, CLEAR, SLOW, ""),
           (3.0, STOP, CLEAR, "obstacle"), (3.5, HOLD, STOP, "obstacle"), (4.0, FAULT, HOLD, "blinded 90 %"),
           (4.1, FAULT, FAULT, "blinded 91 %"),  # the same FAULT, its numbers moving: not yet
           (4.0 + FAULT_RELOG - 0.01, FAULT, FAULT, "silent"),
           (4.0 + FAULT_RELOG, FAULT, FAULT, "silent"),  # lasted: its new reason
           (4.0 + 2 * FAULT_RELOG, FAULT, FAULT, "silent"),  # the one logged
           (4.0 + 2 * FAULT_RELOG, CLEAR, FAULT, "")]
    assert [log.worth(*e) for e in seq] == [False, False, True, False, False, True, True, True, False, False,
                                            True, False, True]
    stuck = DecisionLog()  # a FAULT from the start (a laser whose driver never started): logged once it lasts
    assert [stuck.worth(t, FAULT, None if t == 0.0 else FAULT, "no scan yet") for t in (0.0, 1.0, FAULT_RELOG)] \
        == [False, False, True]


@pytest.mark.parametrize("args,words", [
    ((271, -2.35, 2.35, 0.0, 0.1, 30.0), "angle_increment is 0"),
    ((100, -2.35, 2.35, 0.0174, 0.1, 30.0), "100 ranges"),
    ((271, math.nan, 2.35, 0.0174, 0.1, 30.0), "non-finite"),
    ((271, -2.35, 2.35, 0.0174, 5.0, 1.0), "range_min"),
    ((0, -2.35, 2.35, 0.0174, 0.1, 30.0), "no ranges"),
])
def test_bad_scan_geometry_is_named(args, words):
    with pytest.raises(ScanError, match=words):
        check_scan(*args)


def test_good_scan_geometry_passes():
    check_scan(271, -2.356194, 2.356194, 4.712389 / 270, 0.1, 30.0)


def test_a_clockwise_scan_gives_the_same_points():
    """Some drivers sweep clockwise (angle_min > angle_max, a negative increment; a laser
    mounted upside down often reads so): the same rays, listed the other way round."""
    rng = np.random.default_rng(3)
    ranges = rng.uniform(0.5, 25.0, 271)
    ranges[::17] = np.nan
    ccw = scan_points(ranges, -2.356194, 4.712388 / 270, 0.1, 30.0, (1.6, 0.0, 0.0))
    check_scan(271, 2.356194, -2.356194, -4.712388 / 270, 0.1, 30.0)
    cw = scan_points(ranges[::-1], 2.356194, -4.712388 / 270, 0.1, 30.0, (1.6, 0.0, 0.0))
    assert cw.xy == pytest.approx(ccw.xy[::-1], abs=1e-9)
    assert (cw.n_rays, cw.n_invalid) == (ccw.n_rays, ccw.n_invalid)


# ------------------------------------------------------------------- guard
def make_guard(vehicle, heights=None, **changes):
    return Guard(from_mapping(GuardParams, changes, "test"), vehicle, heights)


def scan(xy, n_rays=None, n_invalid=0):
    from quadrivio_navigation.fields import ScanPoints
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return ScanPoints(xy, n_rays or max(len(xy), 100), n_invalid, 0)


def feed(g, t, speed, handlebar=0.0, front=(), rear=()):
    g.on_state(t, speed, handlebar)
    g.on_pitch(t, 0.0)
    g.on_scan("scan/front", t, scan(front))
    g.on_scan("scan/rear", t, scan(rear))


def test_clear_path_passes_the_request(vehicle):
    g = make_guard(vehicle)
    feed(g, 1.0, 2.0)
    d = g.decide(1.0, 2.0, 0.1)
    assert d.action == CLEAR and d.free == math.inf
    sp = g.command(d, 2.0, 0.1, 0.0)
    assert (sp.speed, sp.handlebar, sp.brake) == (2.0, 0.1, 0.0)


def test_obstacle_in_the_protective_field_stops(vehicle):
    g = make_guard(vehicle)
    front = Footprint.from_vehicle(vehicle, 0.15).front
    feed(g, 1.0, 2.0, front=[[front + 0.8, 0.0]])  # 0.8 m ahead at 2 m/s: inside ~1.4 m
    d = g.decide(1.0, 2.0, 0.0)
    assert d.action == STOP and d.field == "protective" and "protective field" in d.reason
    assert d.protective == pytest.approx(stopping_distance(2.0, 0.15, 3.5) + 0.3)
    assert d.nearest == pytest.approx((front + 0.8, 0.0))
    sp = g.command(d, 2.0, 0.0, 0.0)
    assert sp.speed == 0.0 and sp.brake == 1.0
    assert g.protective_stops == 1
    # braking: still STOP, counted once
    feed(g, 1.1, 1.2, front=[[front + 0.5, 0.0]])
    assert g.decide(1.1, 2.0, 0.0).action == STOP and g.protective_stops == 1
    # the obstacle gone from the field while still braking: STOP for what started it
    feed(g, 1.2, 0.8)
    d = g.decide(1.2, 2.0, 0.0)
    assert d.action == STOP and d.field == "protective" and d.reason.startswith("braking to a stop: obstacle")


def test_warning_field_limits_the_speed_without_a_stop(vehicle):
    g = make_guard(vehicle)
    front = Footprint.from_vehicle(vehicle, 0.15).front
    feed(g, 1.0, 1.0, front=[[front + 3.0, 0.0]])
    d = g.decide(1.0, 2.0, 0.0)
    assert d.action == SLOW and d.field == "warning"
    p = g.p
    assert d.limit == pytest.approx(allowed_speed(d.free - p.warning_margin, p.brake_latency + p.scan_period,
                                                  p.slow_decel))
    assert 0.0 < d.limit < 2.0
    assert g.command(d, 2.0, 0.0, 0.0).speed == pytest.approx(d.limit)
    assert g.command(d, -2.0, 0.0, 0.0).speed == pytest.approx(-d.limit)
    # closer than the warning margin: creep speed down to the creep margin, then limit 0
    # (a gentle hold, no protective stop at rest)
    feed(g, 2.0, 0.0, front=[[front + 0.6, 0.0]])
    d = g.decide(2.0, 2.0, 0.0)
    assert d.limit == pytest.approx(p.creep_speed) and d.action == SLOW
    feed(g, 3.0, 0.0, front=[[front + 0.3, 0.0]])
    d = g.decide(3.0, 2.0, 0.0)
    assert d.limit == 0.0 and d.action == SLOW and g.protective_stops == 0


def test_hold_until_clear_then_release_gradually(vehicle):
    g = make_guard(vehicle, clear_time=1.0, release_accel=0.5)
    front = Footprint.from_vehicle(vehicle, 0.15).front
    feed(g, 1.0, 2.0, front=[[front + 0.5, 0.0]])
    assert g.decide(1.0, 2.0, 0.0).action == STOP
    feed(g, 1.5, 0.0, front=[[front + 0.4, 0.0]])
    assert g.decide(1.5, 2.0, 0.0).action == HOLD
    t = 1.5
    # the obstacle leaves at t = 2: held until 3.0, then the limit rises at 0.5 m/s^2
    actions = {}
    while t < 6.0:
        t = round(t + 0.1, 3)
        feed(g, t, 0.0, front=[[front + 0.4, 0.0]] if t < 2.0 else [])
        d = g.decide(t, 2.0, 0.0)
        actions[t] = (d.action, d.limit)
    assert all(a == HOLD for tt, (a, _) in actions.items() if tt < 2.95)
    assert actions[3.5][0] == SLOW and actions[3.5][1] == pytest.approx(0.25, abs=0.06)
    assert actions[5.9][1] > 1.4


def test_a_motion_no_laser_covers_is_a_fault(vehicle):
    """A vehicle with one laser, ahead: forward is guarded, reversing blind, so refused."""
    g = make_guard(vehicle, scanners=[{"topic": "scan/front", "frame": "laser_front", "covers": "forward"}])
    g.on_state(1.0, 0.0, 0.0)
    g.on_pitch(1.0, 0.0)
    g.on_scan("scan/front", 1.0, scan([]))
    assert g.decide(1.0, 1.0, 0.0).action == CLEAR
    d = g.decide(1.0, -0.5, 0.0)
    assert d.action == FAULT and d.reason == "no scanner covers reverse motion" and d.direction == -1
    assert g.command(d, -0.5, 0.0, 0.0).speed == 0.0
    g.on_state(1.1, -0.4, 0.0)  # already rolling backward (pushed, on a slope): still refused
    assert g.decide(1.1, 0.0, 0.0).action == FAULT


def test_silent_laser_stale_state_and_blindness_are_faults(vehicle):
    g = make_guard(vehicle, scan_timeout=0.35)
    feed(g, 1.0, 2.0)
    assert g.decide(1.0, 2.0, 0.0).action == CLEAR
    g.on_state(1.4, 2.0, 0.0)
    d = g.decide(1.4, 2.0, 0.0)
    assert d.action == FAULT and "scan/front silent for 0.40 s" in d.reason
    assert g.command(d, 2.0, 0.0, 0.0).speed == 0.0
    # the rear laser's silence does not matter going forward ...
    g = make_guard(vehicle)
    feed(g, 1.0, 2.0)
    g.on_state(1.5, 2.0, 0.0)
    g.on_scan("scan/front", 1.5, scan([]))
    assert g.decide(1.5, 2.0, 0.0).action == CLEAR
    # ... but does in reverse
    g.on_state(1.5, -0.5, 0.0)
    d = g.decide(1.5, -0.5, 0.0)
    assert d.action == FAULT and "scan/rear" in d.reason
    # no vehicle state
    g = make_guard(vehicle)
    feed(g, 1.0, 1.0)
    g.on_scan("scan/front", 1.3, scan([]))
    d = g.decide(1.3, 1.0, 0.0)
    assert d.action == FAULT and "vehicle state silent" in d.reason
    # blinded: most rays NaN
    g = make_guard(vehicle)
    feed(g, 1.0, 1.0)
    g.on_scan("scan/front", 1.0, scan([], n_rays=271, n_invalid=200))
    d = g.decide(1.0, 1.0, 0.0)
    assert d.action == FAULT and "blinded" in d.reason
    # no transform for the scanner
    g = make_guard(vehicle)
    feed(g, 1.0, 1.0)
    g.on_scan("scan/front", 1.0, None, "no transform base_link <- laser_front")
    d = g.decide(1.0, 1.0, 0.0)
    assert d.action == FAULT and "no transform" in d.reason


def test_fault_holds_after_it_clears(vehicle):
    g = make_guard(vehicle, clear_time=0.5)
    feed(g, 1.0, 0.0)
    g.on_state(1.5, 0.0, 0.0)
    assert g.decide(1.5, 1.0, 0.0).action == FAULT
    feed(g, 1.6, 0.0)
    assert g.decide(1.6, 1.0, 0.0).action == HOLD
    feed(g, 2.2, 0.0)
    assert g.decide(2.2, 1.0, 0.0).action == SLOW  # released: the ramp starts


def test_self_returns_are_ignored(vehicle):
    g = make_guard(vehicle)
    feed(g, 1.0, 2.0, front=[[1.0, 0.3], [0.0, -0.5]])  # inside the body
    assert g.decide(1.0, 2.0, 0.0).action == CLEAR


def test_downhill_lengthens_the_protective_field(vehicle):
    g = make_guard(vehicle)
    feed(g, 1.0, 2.0)
    flat = g.decide(1.0, 2.0, 0.0).protective
    g2 = make_guard(vehicle)
    g2.on_pitch(3.0, math.radians(10))  # nose down 10 deg, driving forward: downhill
    g2.on_state(3.0, 2.0, 0.0)
    g2.on_scan("scan/front", 3.0, scan([]))
    d = g2.decide(3.0, 2.0, 0.0)
    assert d.slope == pytest.approx(math.radians(10), abs=0.01)
    assert d.protective > flat + 0.2


def test_a_bumps_pitch_is_not_the_grade_without_a_dem(vehicle):
    """Without a DEM the braking slope is the pitch low-passed over slope_smoothing (1 s): a
    bump's face pitching the body 14 deg for 0.2 s moves it by a fifth of that, a slope held
    for 5 s is taken whole."""
    g = make_guard(vehicle)
    for k in range(100):  # 2 s level
        g.on_pitch(k * 0.02, 0.0)
    for k in range(10):  # 0.2 s on a bump's face
        g.on_pitch(2.0 + k * 0.02, math.radians(14))
    g.on_state(2.2, 2.0, 0.0)
    g.on_scan("scan/front", 2.2, scan([]))
    d = g.decide(2.2, 2.0, 0.0)
    assert 0.0 < d.slope < math.radians(14) * 0.25
    for k in range(250):
        g.on_pitch(2.2 + k * 0.02, math.radians(8))
    g.on_state(7.2, 2.0, 0.0)
    g.on_scan("scan/front", 7.2, scan([]))
    assert g.decide(7.2, 2.0, 0.0).slope == pytest.approx(math.radians(8), abs=math.radians(0.1))


def test_with_a_dem_the_slope_is_its_grade_over_the_stopping_distance(vehicle):
    """A DEM falling 10 % toward +x and level beyond x = 3 m: driving +x from x = 0 the
    slope is the mean grade from the vehicle to where it would stop (by hand: the stopping
    distance at that grade, the drop over it), whatever the body's pitch on a bump;
    reversing from there it brakes uphill; without a fresh pose the pitch again."""
    def heights(x, y):
        x = np.asarray(x, dtype=float)
        return -0.1 * np.clip(x, None, 3.0)

    g = make_guard(vehicle, heights)
    g.on_pitch(1.0, math.radians(14))  # a bump's face
    g.on_pose(1.0, 0.0, 0.0, 0.0, 0.1)
    g.on_state(1.0, 2.0, 0.0)
    g.on_scan("scan/front", 1.0, scan([]))
    g.on_scan("scan/rear", 1.0, scan([]))
    d = g.decide(1.0, 2.0, 0.0)
    p = g.p
    slope = 0.0
    for _ in range(2):  # by hand, as dem_slope says
        dist = stopping_distance(2.0, p.brake_latency + p.scan_period, effective_decel(p.brake_decel, slope)) + p.margin
        slope = math.atan2(0.1 * min(dist, 3.0), dist)
    assert 0.0 < d.slope == pytest.approx(slope, abs=1e-12)
    assert d.slope < math.atan(0.1) + 1e-9
    g.on_state(1.05, -1.0, 0.0)  # reversing: uphill, so brakes harder
    assert g.decide(1.05, -1.0, 0.0).slope < 0.0
    g.on_state(2.0, 2.0, 0.0)  # the pose 1 s old: the DEM says nothing, the pitch does
    g.on_pitch(2.0, math.radians(14))
    g.on_scan("scan/front", 2.0, scan([]))
    assert g.decide(2.0, 2.0, 0.0).slope > math.radians(5)


# -------------------------------------------------------------------- zone
SQUARE = ((-10.0, -10.0), (30.0, -10.0), (30.0, 10.0), (-10.0, 10.0))


def test_zone_geometry():
    pts = np.array([[0.0, 0.0], [35.0, 0.0], [29.5, 9.5]])
    assert list(points_in_polygon(pts, np.array(SQUARE))) == [True, False, True]
    assert distance_to_edges(np.array([[0.0, 0.0], [29.0, 0.0]]), np.array(SQUARE)) == pytest.approx([10.0, 1.0])
    check_zone(SQUARE)
    with pytest.raises(ConfigError, match="not a simple polygon"):
        check_zone(((0, 0), (10, 10), (10, 0), (0, 10)))  # a bow tie
    with pytest.raises(ConfigError, match="at least 3"):
        check_zone(((0, 0), (1, 1)))
    with pytest.raises(ConfigError, match="no area"):
        check_zone(((0, 0), (1, 1), (2, 2)))


def test_zone_stops_before_the_edge_and_when_uncertain(vehicle):
    g = make_guard(vehicle, zone=SQUARE)
    feed(g, 1.0, 2.0)
    g.on_pose(1.0, 0.0, 0.0, 0.0, 0.1)
    assert g.decide(1.0, 2.0, 0.0).action == CLEAR
    # front edge 0.7 m from the zone's edge: within the protective distance (1.17 m) + 2 sd
    g.on_pose(1.0, 27.5, 0.0, 0.0, 0.1)
    d = g.decide(1.0, 2.0, 0.0)
    assert d.action == STOP and d.field == "zone" and g.zone_stops == 1
    g = make_guard(vehicle, zone=SQUARE)
    feed(g, 1.0, 2.0)
    g.on_pose(1.0, 0.0, 0.0, 0.0, 1.5)
    d = g.decide(1.0, 2.0, 0.0)
    assert d.action == STOP and "uncertain" in d.reason
    g = make_guard(vehicle, zone=SQUARE)
    feed(g, 1.0, 2.0)
    d = g.decide(1.0, 2.0, 0.0)
    assert d.action == FAULT and "no pose" in d.reason


def test_bad_parameters_are_named(vehicle):
    with pytest.raises((ConfigError, ValueError), match="warning_margin"):
        make_guard(vehicle, margin=1.0, warning_margin=0.5)
    with pytest.raises((ConfigError, ValueError), match="simple polygon"):
        make_guard(vehicle, zone=((0, 0), (10, 10), (10, 0), (0, 10)))


def test_standing_at_the_zone_edge_holds_without_creeping(vehicle):
    g = make_guard(vehicle, zone=SQUARE)
    feed(g, 1.0, 2.0)
    g.on_pose(1.0, 27.0, 0.0, 0.0, 0.1)
    assert g.decide(1.0, 2.0, 0.0).action == STOP and g.zone_stops == 1
    # stopped 2.3 m short of the edge: asked for 2 m/s again, it stays held (the field of
    # the speed asked for reaches the edge), and the stop is counted once
    for k in range(30):
        t = 2.0 + 0.1 * k
        feed(g, t, 0.0)
        g.on_pose(t, 27.0, 0.0, 0.0, 0.1)
        d = g.decide(t, 2.0, 0.0)
        assert d.action == HOLD and d.field == "zone" and d.limit == 0.0
    assert g.zone_stops == 1
    # asked to back away (reverse), it may
    feed(g, 6.0, 0.0)
    g.on_pose(6.0, 27.0, 0.0, 0.0, 0.1)
    assert g.decide(6.0, -0.5, 0.0).field != "zone"
