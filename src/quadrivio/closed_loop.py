"""The closed loop in one process: a scenario run without a ROS master, every part of the
stack that acts on the vehicle composed in sim time, as fast as one core allows.

What runs is what ``sim.launch`` runs, from the same files and the same scenario: the
simulator core with the scenario's ``sim:`` section; each sensor adapter's noise and
latency model (GPS, IMU, magnetometer, both lasers; one generator per adapter, seeded from
the run's seed and the adapter's node name, as the adapters do); the PLC program with its
link latency; the smoother (``localization.yaml``, the simulated magnetometer's
calibration, the scenario's ``localization:``) at its rate; the predictor's model at its
rate (:mod:`quadrivio_localization.predictor`, the port of the roscpp core); the path
publisher; the planner with the local obstacle layer and replanning (scenarios with a map);
the obstacle guard (the roscpp node's core, ``guard_core.h``, by default; the Python
reference, which it matches decision for decision, on request); and the follower on the predicted pose, its requests through the guard to the
PLC. Readings reach their consumers at their delivery time, in delivery order.

Where it differs from the ROS stack, by design:

* **No transport.** A message reaches its subscribers in the physics step it is sent
  (ROS adds 0.1-1 ms on loopback, and a free-running stack's timers drift against the
  simulator's steps); nodes run in a fixed order within a step (deliveries, smoother,
  predictor, layer, planner, follower and guard).
* **Planning takes no sim time.** The simulated world waits while the planner works (in
  ROS the vehicle stands still during a first plan and drives on during a replan, which
  starts from where it will be by then); the planner's time is still measured and
  reported. The lattice stops at ``planning.REPEATABLE_EXPANSIONS`` expansions (or the
  scenario's ``planner: lattice: max_expansions``) instead of its wall-clock budget, so
  that a run repeats. ROS in lockstep does both alike (``experiment --lockstep``).
* **No PLCClient.** The guard's setpoints go to the PLC program directly, in AUTO from the
  start; the PLCClient's own checks (its session, the operator's mode) are not exercised.

The same seed gives the same run, array for array. ROS-free: used by ``campaign
--closed-loop`` and the benchmarks.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, replace_nested

from .metrics import RunData, Series
from .obstacle_metrics import map_bodies
from .offline import GPS_NODE, IMU_NODE, MAG_NODE, _sim_params, localizer_params, sensor_params
from .scenario import Scenario, _defaults, _section
from .scenario import vehicle as scenario_vehicle

MAX_RANGE = 20.0  # [m] the guard's: returns beyond cannot matter for its fields


@dataclass
class Recorder:
    """What ``experiment`` records in its bag, as rows, for :class:`quadrivio.metrics.RunData`."""
    truth: List[tuple] = field(default_factory=list)  # t, x, y, yaw, vx, wz
    estimate: List[tuple] = field(default_factory=list)
    predicted: List[tuple] = field(default_factory=list)
    gps: List[tuple] = field(default_factory=list)  # t, e, n, status
    status: List[tuple] = field(default_factory=list)  # t, status, progress, cross_track
    setpoint: List[tuple] = field(default_factory=list)  # t, speed, handlebar, brake (the guard's)
    vehicle: List[tuple] = field(default_factory=list)  # t, speed, handlebar
    calibration: List[tuple] = field(default_factory=list)
    planner: List[tuple] = field(default_factory=list)  # t, state, planning_time, length
    guard: List[tuple] = field(default_factory=list)
    actors: List[tuple] = field(default_factory=list)
    paths: List[tuple] = field(default_factory=list)  # (t, N x 3 poses)
    local_marks: set = field(default_factory=set)
    gps_decisions: List[tuple] = field(default_factory=list)
    log: List[Tuple[float, str]] = field(default_factory=list)  # (t, line): what the nodes would have logged


@dataclass
class ClosedLoopResult:
    run: RunData
    outcome: str  # completed | aborted: ... | planner failed: ... | time limit
    sim_s: float
    wall_s: float
    cpu_s: float  # this process's CPU time over the run
    log: List[Tuple[float, str]]
    counters: Dict[str, object]
    stop_scenes: List[object] = field(default_factory=list)  # the guard's first stops (stop_views.StopScene)
    stops: int = 0  # how many stops (protective and fail-safe) in all


_series = Series.from_rows


def _config(cls, package: str, name: str, s: Scenario, section: Optional[str]):
    """A node's parameters: its package's config file, then the scenario's section."""
    from quadrivio_description.paths import ros_package_path

    p = _defaults(cls, f"{ros_package_path(package)}/config/{name}")
    over = _section(s.data, section) if section else None
    return replace_nested(p, over, f"{s.path}: {section}") if over else p


def sim_params(s: Scenario, seed: int):
    """The simulator's parameters as ``sim_node`` builds them: ``sim.yaml``, the scenario's
    ``sim:``, its world (:func:`quadrivio_sim.simulator.with_scenario_world`), the run's seed."""
    from quadrivio_sim.simulator import with_scenario_world

    return with_scenario_world(_sim_params(s, seed), s.data.get("actors"), _section(s.data, "map"), s.path, s.path)


def _mount(vehicle, frame: str):
    """A sensor frame's (translation (3,), rotation 3 x 3) in base_link (vehicle.yaml)."""
    from quadrivio_description.frames import rpy_matrix

    sensor = vehicle.sensors.get(frame)
    if sensor is None:
        raise ConfigError(f"vehicle.yaml has no sensor frame '{frame}' (the scanners' mounts)")
    return np.asarray(sensor.xyz, float), np.array(rpy_matrix(tuple(sensor.rpy)))


class _Delivery:
    """Messages in flight: delivered in time order, ties in the order sent."""

    def __init__(self) -> None:
        self.q: List[tuple] = []
        self.n = 0

    def push(self, at: float, kind: str, data) -> None:
        heapq.heappush(self.q, (at, self.n, kind, data))
        self.n += 1

    def due(self, t: float):
        while self.q and self.q[0][0] <= t + 1e-9:
            yield heapq.heappop(self.q)


GUARDS = ("guard_cpp", "guard")  # the roscpp node's core (the launch files' default), the Python reference


def run(s: Scenario, seed: int, progress: Optional[Callable[[float, float], None]] = None,
        max_duration: Optional[float] = None, guard_impl: str = "guard_cpp") -> ClosedLoopResult:
    """Run scenario ``s`` with ``seed`` closed loop (see module docstring); ``progress(t,
    t_end)`` every simulated second; ``guard_impl`` as sim.launch's ``guard``: ``guard_cpp``
    (the roscpp node's core, through :mod:`quadrivio_navigation.guard_native`) or ``guard``
    (the Python reference)."""
    if guard_impl not in GUARDS:
        raise ValueError(f"guard_impl must be one of {', '.join(GUARDS)}, got {guard_impl!r}")
    from quadrivio_description.site import load_site
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_description.frames import rpy_matrix
    from quadrivio_localization.predictor import Predictor, PredictorParams, predicted
    from quadrivio_localization.smoother import Localizer
    from quadrivio_description.attitude import Attitude, imu_lever
    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.fields import ScanError, check_scan, rep117_ranges, scan_points
    from quadrivio_navigation.follower import ABORTED, DONE, FOLLOWING, FollowerConfig, PurePursuit, make_route
    from quadrivio_navigation.guard import (ACTION_NAMES, FAULT, HOLD, STOP, DecisionLog, Guard, GuardNodeParams,
                                            GuardParams, load_zone_file)
    from quadrivio_navigation.local_layer import (LocalLayer, LocalLayerNodeParams, LocalLayerParams, scan_ground,
                                                  scan_in_map, terrain_ground, wheel_centres)
    from quadrivio_navigation.maps import OccupancyGrid as Grid
    from quadrivio_navigation.maps import load_map
    from quadrivio_navigation.paths import PathParams, path_points
    from quadrivio_navigation.planning import Planner, PlannerParams, path_length, repeatable
    from quadrivio_navigation.replanning import (DetourWait, HeldPoints, PlannerNodeParams, blocked_reason,
                                                 known_distance, mark_discs, merge_local, remaining_length,
                                                 replan_start)
    from quadrivio_navigation.rollover import RolloverParams
    from quadrivio_plc import protocol
    from quadrivio_plc.client import Multiplexer, PlcClientParams
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.adapter_params import (GpsAdapterParams, ImuAdapterParams, LaserAdapterParams,
                                              MagAdapterParams)
    from quadrivio_sim.noise import driver_ranges, sensor_models
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.simulator import Simulator
    from quadrivio_sim.world import quat_to_rpy
    from quadrivio_terrain.terrain import known_heightfield

    from .stop_views import MAX_VIEWS, StopScene, stopped_something

    wall0, cpu0 = time.perf_counter(), time.process_time()
    v, site = scenario_vehicle(s, load_vehicle()), load_site()
    wheels = wheel_centres(v)  # the guard's and the layer's ground test stand the vehicle on them
    frame = site.local_frame()
    sp = sim_params(s, seed)
    sim = Simulator(sp, v, load_actuators(package_file("config", "actuators.yaml")), build_urdf(v), site)
    for name in ("image", "joint_states"):
        if name in sim.enabled:
            sim.enabled[name] = False
    rec = Recorder()

    def log(t: float, text: str) -> None:
        rec.log.append((t, text))

    # ---- sensor adapters: the same models, generators and names as sensor_adapters'
    gps, gps_lat = sensor_models("gps", sensor_params(s, "gps", GpsAdapterParams, "gps.yaml"), seed, GPS_NODE)
    imu, imu_lat = sensor_models("imu", sensor_params(s, "imu", ImuAdapterParams, "imu.yaml"), seed, IMU_NODE)
    mag, mag_lat = sensor_models("mag", sensor_params(s, "mag", MagAdapterParams, "mag.yaml"), seed, MAG_NODE)
    lasers = {}
    for f in sp.sensors.lasers.frames:
        lp_ = sensor_params(s, f, LaserAdapterParams, "laser.yaml")
        lasers[f] = (lp_,) + tuple(sensor_models("laser", lp_, seed, "/" + f))

    # ---- localization
    lp = localizer_params(s)
    loc = Localizer(lp, v, site)
    pred_p = _config(PredictorParams, "quadrivio_localization", "predictor.yaml", s, None)
    predictor = Predictor(v.wheelbase, v.steering.ratio, v.steering.max_angle * v.steering.ratio)
    cal_period, last_cal = 1.0, -math.inf

    # ---- the scenario's known terrain (the guard's and the layer's DEM, the planner's slopes)
    hf = known_heightfield(sp.terrain, np.random.default_rng(seed), frame if sp.terrain.kind == "geotiff" else None)
    heights = None if hf is None else hf.heights

    # ---- the guard
    gnode = _config(GuardNodeParams, "quadrivio_navigation", "guard.yaml", s, None)
    gp = _config(GuardParams, "quadrivio_navigation", "guard.yaml", s, "guard")
    if gnode.zone_file and not gp.zone:
        gp = replace_nested(gp, {"zone": [list(z) for z in load_zone_file(gnode.zone_file)]}, "zone_file")
    g_heights = heights if gnode.terrain_from_scenario else None
    if guard_impl == "guard_cpp":
        from quadrivio_navigation.guard_native import NativeGuard
        guard = NativeGuard(gp, v, hf if gnode.terrain_from_scenario else None, gnode)
    else:
        guard = Guard(gp, v, g_heights)
    lever = imu_lever(v)
    g_att = Attitude(gp.slope_tau, lever=lever)
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = rpy_matrix(
        v.sensors["imu_link"].rpy if "imu_link" in v.sensors else (0.0, 0.0, 0.0))

    def mount_imu(a):
        """imu_link -> base_link (the guard's and the layer's rotate(imu_mount, .), its matrix once)."""
        return (r00 * a[0] + r01 * a[1] + r02 * a[2], r10 * a[0] + r11 * a[1] + r12 * a[2],
                r20 * a[0] + r21 * a[1] + r22 * a[2])
    scanner_of = {sc.frame: sc for sc in gp.scanners}
    request: Optional[tuple] = None  # (received, speed, handlebar, brake)
    last_action = None

    # ---- navigation
    pathp = _config(PathParams, "quadrivio_navigation", "path.yaml", s, "path")
    fp = _config(FollowerConfig, "quadrivio_navigation", "follower.yaml", s, "follower")
    follower: Optional[PurePursuit] = None
    grid = None
    planner = None
    pnode = _config(PlannerNodeParams, "quadrivio_navigation", "planner.yaml", s, None)
    plp = _config(PlannerParams, "quadrivio_navigation", "planner.yaml", s, "planner")
    plp = repeatable(plp)  # bounded by expansions: a run repeats
    layer = None
    if sp.map.file:
        grid = load_map(sp.map.file, frame)
        known = known_distance(grid)
        planner = Planner(grid, v, plp, heights if pnode.terrain_from_scenario else None, RolloverParams())
        lnode = _config(LocalLayerNodeParams, "quadrivio_navigation", "local_layer.yaml", s, None)
        llp = _config(LocalLayerParams, "quadrivio_navigation", "local_layer.yaml", s, "local_layer")
        layer = LocalLayer(llp)
        l_att = Attitude(lever=lever)
        l_heights = heights if lnode.terrain_from_scenario else None
        l_no_return = {sc.frame: sc.no_return for sc in (lnode.scanners or gp.scanners)}
    goal = tuple(pathp.goal) if pathp.kind == "goal" else None
    if layer is not None and goal is None and lnode.only_with_goal:
        layer = None  # the planner has no goal: the node reads no scans (only_with_goal)
    if goal is not None and planner is None:
        raise ConfigError(f"{s.path}: path kind 'goal' needs a map (the map: section)")
    path_poses: Optional[np.ndarray] = None
    planner_state = 0  # PlannerStatus: IDLE, PLANNING, FOUND, FAILED, BLOCKED
    planner_reason = ""
    local_grid = None
    last_try = -math.inf
    block_why = ""
    detour = DetourWait(pnode.detour_wait, pnode.detour_margin)  # drive round what blocks the path, or wait?
    plan_wall: List[float] = []
    replans = 0

    mounts = {f: _mount(v, f) for f in lasers}
    pose = None  # the newest prediction: (stamp, x, y, yaw, speed, sd)
    est_sd = 0.0
    started = False
    t_end = max_duration if max_duration is not None else s.run.max_duration
    outcome = "time limit"
    done_at: Optional[float] = None
    follow_steps = max(1, int(round(1.0 / (fp.rate * sim.dt))))
    loc_steps = max(1, int(round(1.0 / (lp.rate * sim.dt))))
    pred_steps = max(1, int(round(1.0 / (pred_p.rate * sim.dt))))
    layer_steps = max(1, int(round(1.0 / (2.0 * sim.dt))))
    check_steps = max(1, int(round(1.0 / (pnode.check_rate * sim.dt)))) if pnode.check_rate > 0 else 0
    inflight = _Delivery()
    counters: Dict[str, object] = {"smoother_restarts": 0, "scans_rejected": 0, "guard_stops_sent_on_scan": 0}
    # the PLCClient: its multiplexer (a stale autonomous setpoint becomes a stop) at its send rate, in AUTO
    # from the start (experiment's initial_mode)
    cp = _config(PlcClientParams, "quadrivio_plc", "plc_client.yaml", s, None)
    mux = Multiplexer(cp.setpoint_timeout, cp.stop_brake)
    client_steps = max(1, int(round(1.0 / (cp.send_rate * sim.dt))))
    sim.plc.force_auto(0.0)

    def new_route(poses: np.ndarray, t: float) -> None:
        nonlocal follower
        old = follower
        speed = pose[4] if pose is not None and old is not None and old.status == FOLLOWING else 0.0
        route = make_route(poses, fp.profile, fp.pure_pursuit.reverse_speed, v_start=speed)
        last = (old.sp_speed, old.sp_handlebar, old.t_last) if old is not None and old.status == FOLLOWING else \
            (0.0, 0.0, None)
        follower = PurePursuit(fp.pure_pursuit, route, v, *last)
        follower.set_limits(fp.profile.accel, fp.profile.decel)
        rec.paths.append((t, np.asarray(poses)[:, :2].copy()))

    def set_planner(t: float, state: int, reason: str, took: float = math.nan, length: float = math.nan) -> None:
        nonlocal planner_state, planner_reason
        if state == 4 and reason != planner_reason:
            log(t, f"planner: BLOCKED: {reason}")
        planner_state, planner_reason = state, reason
        rec.planner.append((t, state, took, length))

    def plan(t: float, start, on, why: str = "", blocked: bool = True) -> None:
        """A first plan (``why`` empty) or a replan on the grid ``on`` (``blocked``: because the
        path is, and a long way round waits for it to clear: :class:`DetourWait`)."""
        nonlocal path_poses, last_try, block_why, replans
        last_try = t
        p = planner if not why else Planner(on, v, plp, heights if pnode.terrain_from_scenario else None,
                                            RolloverParams())
        prefix = np.zeros((0, 3))
        if why:
            block_why = why
            occupied = p.check_pose(goal, "goal")
            detour.waiting = False  # until a way round is put off: with none, retried every pnode.retry s
            if occupied:
                set_planner(t, 4, f"{why}; and the goal is blocked: {occupied}")
                return
            here = start
            prefix, start = replan_start(path_poses, start, pose[4] if pose else 0.0, 0.5, p.path_collides)
            log(t, f"planner: {why}: replanning from ({start[0]:.2f}, {start[1]:.2f})")
        w0 = time.perf_counter()
        r = p.plan(start, goal)  # bounded by expansions, whatever ~replan_budget says: a run repeats
        plan_wall.append(time.perf_counter() - w0)
        if not r.ok:
            if why:
                set_planner(t, 4, f"{why}; no other path: {r.reason}", r.planning_time)
            else:
                set_planner(t, 3, r.reason, r.planning_time)
                log(t, f"planner: FAILED: {r.reason}")
            return
        if why and blocked:
            extra = path_length(prefix) + r.length - remaining_length(path_poses, here)
            if not detour.take(t, extra):
                set_planner(t, 4, f"{why}; waiting up to {detour.left(t):.1f} s for it to clear: the way round is "
                                  f"{extra:.0f} m longer")
                return
        detour.clear()
        poses = np.concatenate([prefix, r.poses]) if len(prefix) else r.poses
        path_poses = poses
        guard_held[1] = None  # held since: the new path is followed from here
        replans += bool(why)
        set_planner(t, 2, f"replanned ({why})" if why else r.note, r.planning_time, r.length)
        log(t, f"planner: {'replanned' if why else 'path'} of {r.length:.1f} m, {r.cusps} cusp(s), "
               f"{r.expansions} expansions in {r.planning_time:.2f} s")
        new_route(poses, t)

    def on_first_estimate(t: float, e) -> None:
        """The path publisher: the path from where the vehicle is, or the goal to the planner."""
        nonlocal started
        started = True
        if goal is not None:
            rec_goal[0] = goal
            plan(t, (e.x, e.y, e.theta), grid)
            return
        th = e.theta
        c, sn = math.cos(th), math.sin(th)
        wps = [(e.x + c * x - sn * y, e.y + sn * x + c * y) for x, y in pathp.waypoints]
        pts = path_points(pathp.kind, (e.x, e.y, th), pathp.figure_eight, wps, pathp.ds)
        heading = np.arctan2(np.gradient(pts[:, 1]), np.gradient(pts[:, 0]))
        new_route(np.column_stack([pts, heading]), t)

    rec_goal = [None]

    def guard_status(t: float, d, requested: float, handlebar: float) -> None:
        st = guard.state
        v_m, h_m = (st[1], st[2]) if st is not None else (math.nan, math.nan)
        if glog.worth(t, d.action, rec.guard[-1][1] if rec.guard else None, d.reason):  # as the node logs it
            log(t, f"guard {ACTION_NAMES[d.action]}{': ' + d.reason if d.reason else ''}")
        if stopped_something(d.action, v_m) and (not rec.guard or rec.guard[-1][1] != d.action):
            stops[0] += 1
            if len(stops[1]) < MAX_VIEWS:  # what it saw, for the stop's picture (stop_views)
                stops[1].append(StopScene(
                    t, d.action, d.field, d.reason, d.scanner, d.direction, requested, v_m, handlebar, h_m,
                    d.protective, d.warning, d.free, d.nearest, {k: xy for k, (_, xy) in seen_scans.items()},
                    {k: t - stamp for k, (stamp, _) in seen_scans.items()}, "the vehicle description"))
        rec.guard.append((t, d.action, d.limit, d.free, d.protective, d.scan_stamp if math.isfinite(d.scan_stamp)
                          else 0.0, d.direction, requested, 1.0 if d.field == "zone" else 0.0, v_m, handlebar, h_m))
        if d.action in (STOP, HOLD, FAULT) or d.limit < fp.pure_pursuit.min_speed:
            guard_held[0] = t + 0.3
        held = d.action in (STOP, HOLD) or (d.limit < 0.05 and abs(requested) > 0.1)
        held_points.update(held, pose[1:4] if pose is not None else None, d.nearest)
        if not held:
            guard_held[1] = None
        elif guard_held[1] is None:
            guard_held[1] = t

    guard_held = [-1.0, None]  # the follower's held_until, the planner's held_since
    glog = DecisionLog()
    seen_scans: Dict[str, Tuple[float, np.ndarray]] = {}  # topic -> (stamp, points in base_link) the guard last read
    stops: List[object] = [0, []]  # how many stops, the first MAX_VIEWS as scenes
    held_points = HeldPoints()

    def send(t: float, speed: float, handlebar: float, brake: float) -> None:
        """The guard's setpoint to the PLCClient, which forwards it at once in AUTO."""
        mux.update(protocol.SOURCE_AUTO, t, speed, handlebar, brake)
        rec.setpoint.append((t, speed, handlebar, brake))
        plc_client(t)

    def plc_client(t: float) -> None:
        for fr in mux.frames(protocol.MODE_AUTO, t):
            sim.plc.setpoint(fr.source, fr.speed, fr.handlebar, fr.brake, t)

    def on_scan(t: float, frame_: str, smp, ranges) -> None:
        nonlocal last_action
        sc = scanner_of.get(frame_)
        stamp = smp.stamp
        try:
            check_scan(len(ranges), smp.angle_min, smp.angle_min + smp.angle_increment * (len(ranges) - 1),
                       smp.angle_increment, smp.range_min, smp.range_max)
        except ScanError as exc:
            counters["scans_rejected"] += 1
            log(t, f"scan {frame_} rejected: {exc}")
            return
        t_b, R_b = mounts[frame_]
        # the local layer (with a fresh pose)
        if layer is not None and pose is not None and t - pose[0] <= 0.5:
            sensor, bearings, rr = scan_in_map(*pose[1:4], t_b, R_b, smp.angle_min, smp.angle_increment,
                                               rep117_ranges(ranges, smp.range_max, l_no_return.get(frame_, "inf")),
                                               smp.range_min, smp.range_max)
            ground = None
            if l_heights is not None:
                lp = layer.p
                ground = terrain_ground(l_heights, pose[1:4] + (pose[5],), l_att.roll, l_att.pitch, v.wheel_radius,
                                        t_b, R_b, lp.ground_tolerance, lp.ground_tolerance_per_m,
                                        lp.ground_position_sigmas, lp.ground_tolerance_max, wheels=wheels)
            layer.add_scan(stamp, sensor, bearings, rr, ground)
        if sc is None:
            return
        if t - stamp > gp.max_scan_age:
            counters["scans_rejected"] += 1
            return
        rr = ranges = rep117_ranges(ranges, smp.range_max, sc.no_return)  # the driver's "nothing seen" as +inf
        if g_heights is not None and pose is not None and t - pose[0] <= 0.5:
            ground = terrain_ground(g_heights, pose[1:4] + (pose[5],), g_att.roll, g_att.pitch, v.wheel_radius, t_b,
                                    R_b, gnode.ground_tolerance, 0.0, gnode.ground_position_sigmas,
                                    gnode.ground_tolerance_max, gnode.ground_position_sd_min, wheels)
            gr = scan_ground(ground, ranges, smp.angle_min, smp.angle_increment, smp.range_min, smp.range_max,
                             MAX_RANGE)
            if gr.any():
                rr = np.where(gr, np.inf, ranges)
        yaw_b = math.atan2(R_b[1, 0], R_b[0, 0])
        points = scan_points(rr, smp.angle_min, smp.angle_increment, smp.range_min, smp.range_max,
                             (float(t_b[0]), float(t_b[1]), yaw_b), MAX_RANGE, R_b)
        guard.on_scan(sc.topic, stamp, points, "")
        seen_scans[sc.topic] = (stamp, points.xy)
        fresh = request is not None and t - request[0] <= gnode.request_timeout
        speed, hb, brake = (request[1], request[2], request[3]) if fresh else (0.0, 0.0, 0.0)
        d = guard.decide(t, speed, hb)
        stop_now = fresh and d.action in (STOP, FAULT) and last_action not in (STOP, FAULT)
        out = guard.command(d, speed, hb, brake)
        last_action = d.action
        if stop_now:
            counters["guard_stops_sent_on_scan"] += 1
            send(t, out.speed, out.handlebar, out.brake)
        guard_status(t, d, speed, hb)

    def on_request(t: float, c) -> None:
        nonlocal request, last_action
        request = (t, c.speed, c.handlebar, c.brake)
        d = guard.decide(t, c.speed, c.handlebar)
        out = guard.command(d, c.speed, c.handlebar, c.brake)
        before, last_action = last_action, d.action
        send(t, out.speed, out.handlebar, out.brake)
        if d.action != before:
            guard_status(t, d, c.speed, c.handlebar)

    while sim.t < t_end - 1e-9:
        due = sim.step()
        t = sim.t
        for name, x in due:
            if name == "ground_truth":
                yaw = quat_to_rpy(x.orientation)[2]
                c, sn = math.cos(yaw), math.sin(yaw)
                rec.truth.append((x.stamp, x.position[0], x.position[1], yaw,
                                  x.linear_velocity[0] * c + x.linear_velocity[1] * sn, x.angular_velocity[2]))
            elif name == "plc_state":
                inflight.push(t, "state", (x.plc_time, x.wheel_speed, x.handlebar))
            elif name == "imu":
                f, w = imu.apply(x.specific_force, x.angular_rate)
                inflight.push(imu_lat.deliver_at(x.stamp), "imu", (x.stamp, *map(float, f), *map(float, w)))
            elif name == "mag":
                inflight.push(mag_lat.deliver_at(x.stamp), "mag", (x.stamp, *map(float, mag.apply(x.field))))
            elif name == "gps":
                r = gps.apply(x.stamp, x.position, x.velocity)
                if r.position is None:
                    data = (x.stamp, math.nan, math.nan, math.nan, math.nan, math.nan, r.status)
                    rec.gps.append((x.stamp, math.nan, math.nan, r.status))
                else:
                    lat, lon, alt = frame.enu_to_lla(*r.position)
                    data = (x.stamp, lat, lon, alt, r.variances[0], r.variances[1], r.status)
                    rec.gps.append((x.stamp, r.position[0], r.position[1], r.status))
                inflight.push(gps_lat.deliver_at(x.stamp), "gps", data)
            elif name == "scan":
                lp_, noise, lat_ = lasers[x.frame]
                if lp_.noise.is_silent(x.stamp):
                    continue
                ranges = driver_ranges(noise.apply(x.ranges, x.range_min, x.range_max), x.range_max, lp_.no_return)
                inflight.push(lat_.deliver_at(x.stamp), "scan", (x.frame, x, ranges))
            elif name == "actors":
                rec.actors.append((t, [(a.name, a.kind, a.shape, a.x, a.y, a.yaw, a.size[0], a.size[1]) for a in x]))
        for _, _, kind, data in inflight.due(t):
            if kind == "state":
                st, ws, hb = data
                loc.add_vehicle_state(st, ws, hb)
                predictor.add_reading(st, ws, hb)
                guard.on_state(st, ws, hb)
                g_att.add_speed(st, ws)
                if layer is not None:
                    l_att.add_speed(st, ws)
                rec.vehicle.append((st, ws, hb))
            elif kind == "imu":
                loc.add_imu(data[0], data[1:4], data[4:7])
                fi, wi = mount_imu(data[1:4]), mount_imu(data[4:7])
                g_att.add_imu(data[0], fi, wi)
                guard.on_pitch(data[0], g_att.pitch)
                if layer is not None:
                    l_att.add_imu(data[0], fi, wi)
            elif kind == "mag":
                loc.add_mag(data[0], data[1:4])
            elif kind == "gps":
                loc.add_gps(*data)
            else:
                on_scan(t, *data)
        steps = sim.steps
        if steps % loc_steps == 0:
            try:
                e = loc.update(t)
            except RuntimeError as exc:
                log(t, f"smoother update failed ({str(exc).strip().splitlines()[0]}): restarted")
                counters["smoother_restarts"] += 1
                loc = Localizer(lp, v, site)
                e = None
            for dec in loc.pop_gps_decisions():
                rec.gps_decisions.append(dec)
            for ev in loc.pop_events():
                log(t, f"localization: {ev}")
            if e is not None:
                rec.estimate.append((e.stamp, e.x, e.y, e.theta, e.speed, e.yaw_rate))
                predictor.set_estimate(e.stamp, e.x, e.y, e.theta)
                est_sd = math.sqrt(max(e.covariance[0, 0], e.covariance[1, 1], 0.0))
                if t - last_cal >= cal_period:
                    last_cal = t
                    cal = e.calibration
                    predictor.set_calibration(cal["wheel_speed_scale"], cal["handlebar_offset"], cal["steering_gain"])
                    sig = loc.calibration_sigma()
                    rec.calibration.append((e.stamp, cal["wheel_speed_scale"], cal["handlebar_offset"],
                                            cal["steering_gain"], cal.get("gyro_bias", math.nan),
                                            cal.get("mag_hard_iron_x", math.nan), cal.get("mag_hard_iron_y", math.nan),
                                            *[sig.get(k, math.nan) for k in ("wheel_speed_scale", "handlebar_offset",
                                                                              "steering_gain", "gyro_bias",
                                                                              "mag_hard_iron_x", "mag_hard_iron_y")]))
                if not started:
                    on_first_estimate(t, e)
        if steps % pred_steps == 0:
            stamp, ppose, twist, _why = predicted(predictor, pred_p, t)
            if stamp is not None:
                pose = (stamp, ppose[0], ppose[1], ppose[2], twist[0], est_sd)
                rec.predicted.append((stamp, ppose[0], ppose[1], ppose[2], twist[0], twist[1]))
                guard.on_pose(stamp, ppose[0], ppose[1], ppose[2], est_sd)
        if layer is not None and steps % layer_steps == 0 and layer.placed:
            vals = layer.grid_values()
            local_grid = Grid(vals.copy(), layer.p.resolution, (layer.origin[0], layer.origin[1], 0.0))
            rows_, cols_ = np.nonzero(vals >= 100)
            if len(rows_):
                r_ = layer.p.resolution
                rec.local_marks.update(zip(np.round(layer.origin[0] + (cols_ + 0.5) * r_, 1),
                                           np.round(layer.origin[1] + (rows_ + 0.5) * r_, 1)))
        if check_steps and planner is not None and goal is not None and local_grid is not None and pose is not None \
                and steps % check_steps == 0:
            cur = pose[1:4]
            merged = None
            if planner_state == 4 and detour.waiting:  # for the path to clear
                why = blocked_reason(path_poses, cur, local_grid, planner.footprint, pnode.check_horizon, grid,
                                     known, pnode.known_tolerance)
                if not why:
                    log(t, f"planner: the path cleared, {t - detour.since:.1f} s after it was blocked: going on")
                    detour.resume(t)
                    found = [row for row in rec.planner if row[1] == 2]
                    set_planner(t, 2, "the path cleared", *(found[-1][2:] if found else ()))
                elif detour.left(t) <= 0.0:  # the way round, from where the guard holds the vehicle: kept
                    # held_clearance from what it held it for, as after held_replan
                    merged = mark_discs(merge_local(grid, local_grid, known, pnode.known_tolerance),
                                        held_points.near(cur[0], cur[1]), pnode.held_clearance, planner.footprint, cur)
                    plan(t, cur, merged, why)
            elif planner_state == 4:
                if t - last_try >= pnode.retry:
                    merged = merge_local(grid, local_grid, known, pnode.known_tolerance)
                    plan(t, cur, merged, block_why)
            elif planner_state == 2 and path_poses is not None:
                why = blocked_reason(path_poses, cur, local_grid, planner.footprint, pnode.check_horizon, grid,
                                     known, pnode.known_tolerance)
                hs = guard_held[1]
                held_why = not why and hs is not None and t - hs >= pnode.held_replan and t - last_try >= pnode.retry
                if held_why:
                    why = f"the obstacle guard has held the vehicle for {t - hs:.0f} s"
                elif why:
                    detour.blocked(t)
                if why:
                    merged = merge_local(grid, local_grid, known, pnode.known_tolerance)
                    if held_why:
                        merged = mark_discs(merged, held_points.near(cur[0], cur[1]), pnode.held_clearance,
                                            planner.footprint, cur)
                    plan(t, cur, merged, why, not held_why)
        if steps % follow_steps == 0 and follower is not None and pose is not None:
            age = max(0.0, t - pose[0])
            cmd = follower.update(pose[1], pose[2], pose[3], pose[4], pose_age=age, t=t,
                                  held=t <= guard_held[0])
            rec.status.append((t, cmd.status, cmd.progress, cmd.cross_track))
            on_request(t, cmd)
            if cmd.status in (DONE, ABORTED) and done_at is None and s.run.end == "path_done":
                done_at = t
                outcome = "completed" if cmd.status == DONE else f"aborted: {cmd.reason}"
        if steps % client_steps == 0:
            plc_client(t)
        if planner_state == 3 and s.run.end == "path_done" and (follower is None or follower.status != FOLLOWING):
            outcome = f"planner failed: {planner_reason}"
            break
        if progress is not None and steps % 100 == 0:
            progress(t, t_end)
        if done_at is not None:
            break
    if done_at is None and s.run.end == "duration":
        outcome = "completed"
    sim_s = sim.t
    contacts = [(c.stamp, c.body, c.kind, c.speed) for c in sim.contacts]
    sim.close()
    counters.update({"replans": replans, "plans": len(plan_wall),
                     "plan_wall_s_max": max(plan_wall) if plan_wall else None})
    pose_cols = ("x", "y", "yaw", "vx", "wz")
    cal_names = ("wheel_speed_scale", "handlebar_offset", "steering_gain", "gyro_bias", "mag_hard_iron_x",
                 "mag_hard_iron_y")
    paths = rec.paths
    run_data = RunData(
        ground_truth=_series(rec.truth, pose_cols),
        estimate=_series(rec.estimate, pose_cols),
        predicted=_series(rec.predicted, pose_cols),
        gps=_series(rec.gps, ("e", "n", "status")),
        gps_decisions=rec.gps_decisions,
        path=paths[-1][1] if paths else None,
        status=_series(rec.status, ("status", "progress", "cross_track")),
        lever=tuple(v.sensors["gps_link"].xyz[:2]),
        setpoint=_series(rec.setpoint, ("speed", "handlebar", "brake")),
        vehicle=_series(rec.vehicle, ("speed", "handlebar")),
        calibration=_series(rec.calibration, cal_names + tuple(n + "_sigma" for n in cal_names)),
        goal=rec_goal[0],
        map=grid,
        planner=_series(rec.planner, ("state", "planning_time", "length")),
        path_poses=path_poses,
        footprint=Footprint.from_vehicle(v) if grid is not None else None,
        guard=_series(rec.guard, ("action", "limit", "free", "protective", "scan_stamp", "direction", "requested",
                                  "zone", "measured", "handlebar_requested", "handlebar_measured")),
        actors=rec.actors,
        map_bodies=map_bodies(sim.map_blocks) if sim.map_blocks else None,
        paths=paths,
        local_marks=np.array(sorted(rec.local_marks)) if rec.local_marks else np.zeros((0, 2)),
        contacts=contacts if (rec.actors or grid is not None) else None,
    )
    return ClosedLoopResult(run_data, outcome, sim_s, time.perf_counter() - wall0, time.process_time() - cpu0,
                            rec.log, counters, stops[1], stops[0])


def write_run(r: ClosedLoopResult, s: Scenario, seed: int, out: str, vehicle=None,
              plots: bool = True) -> Dict[str, object]:
    """``out/metrics.json`` (the keys ``experiment`` writes, and this process's CPU), the plots
    (unless ``plots`` is false), ``run_info.json`` and ``log.txt`` of a run; each file complete
    or absent."""
    import datetime as dt
    import json
    import os

    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_runtime.files import atomic_write

    from . import metrics as metrics_mod

    v = vehicle if vehicle is not None else scenario_vehicle(s, load_vehicle())
    m = metrics_mod.compute(r.run, s.name, seed, r.wall_s, v)
    metrics_mod.settle_completed(m, s.run.end, r.outcome)
    m.update({"runner": "in_process", "outcome": r.outcome, "cpu_s": r.cpu_s,
              "sim_s_per_cpu_s": r.sim_s / r.cpu_s if r.cpu_s > 0 else None})
    os.makedirs(out, exist_ok=True)

    def put(name: str, text: str) -> None:
        atomic_write(os.path.join(out, name), text)

    put("metrics.json", json.dumps(m, indent=2, default=float) + "\n")
    put("run_info.json", json.dumps({"scenario": s.name, "scenario_file": s.path, "seed": seed, "runner": "in_process",
                                     "outcome": r.outcome, "end": s.run.end, "sim_duration_s": r.sim_s,
                                     "wall_duration_s": r.wall_s,
                                     "cpu_s": r.cpu_s, "counters": r.counters,
                                     "date": dt.datetime.now(dt.timezone.utc).isoformat(timespec="seconds")},
                                    indent=2, default=float) + "\n")
    put("log.txt", "".join(f"{t:9.3f} {line}\n" for t, line in r.log))
    if plots:
        plot_run(r, s, seed, out, v)
    return m


def plot_run(r: ClosedLoopResult, s: Scenario, seed: int, out: str, vehicle=None) -> List[str]:
    """A run's plots (trajectory, errors, control, calibration, guard) in ``out``, and a
    picture of each of the guard's first stops (``stops/``, :mod:`quadrivio.stop_views`)."""
    import os

    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_navigation.guard import GuardParams

    from .plots import all_plots
    from .stop_views import add_world, write_views

    os.makedirs(out, exist_ok=True)
    title = f"{s.name}, seed {seed} (in process)"
    made = all_plots(r.run, out, title)
    if r.stop_scenes:
        v = vehicle if vehicle is not None else scenario_vehicle(s, load_vehicle())
        padding = _config(GuardParams, "quadrivio_navigation", "guard.yaml", s, "guard").padding
        made += write_views([add_world(sc, r.run) for sc in r.stop_scenes], v, padding, out, title)
    return made
