"""A scenario run without a ROS master: the simulator core, the sensor models, the follower
and the smoother in one process, in sim time, as fast as the CPU allows.

What runs is what the launch files run, minus the transport: the simulator with the
scenario's ``sim:`` section, each sensor adapter's noise and latency model with the
scenario's ``sensors:`` overrides (one generator per adapter, seeded from the run's seed
and the adapter's node name, as the nodes do), the PLC program, the follower on the
scenario's path, and the smoother with ``localization.yaml``, the simulated
magnetometer's calibration (``sim.launch``'s default) and the scenario's
``localization:`` section. Readings reach the smoother at their delivery time, in
delivery order, and the smoother updates at its rate.

The follower steers on the ground truth, not on the estimate under test: the trajectory,
and so every sensor reading, is then a function of the scenario and the seed alone, and
any estimator fed :attr:`OfflineRun.inputs` (robot_localization, in ``bench``) sees exactly
the readings ours saw. (``experiment`` runs the closed loop, on the estimate.)

ROS-free: used by ``campaign``, the benchmarks and the localization tests.
"""

from __future__ import annotations

import heapq
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, load_yaml, replace_nested

from .scenario import Scenario, _defaults, _section
from .scenario import vehicle as scenario_vehicle

# The adapters' names in the launch files: their generators' stream ids.
GPS_NODE, IMU_NODE, MAG_NODE = "/gps_adapter", "/imu_adapter", "/mag_adapter"
SETTLE = 20.0  # [s] error statistics start here (the smoother's start-up and first calibration)


@dataclass
class Inputs:
    """Every reading the smoother received, in delivery order (arrays of rows)."""
    state: List[Tuple[float, float, float, float]] = field(default_factory=list)  # delivered, stamp, speed, handlebar
    imu: List[Tuple[float, ...]] = field(default_factory=list)  # delivered, stamp, fx, fy, fz, wx, wy, wz
    mag: List[Tuple[float, ...]] = field(default_factory=list)  # delivered, stamp, mx, my, mz [T]
    gps: List[Tuple[float, ...]] = field(default_factory=list)  # delivered, stamp, lat, lon, alt, var_e, var_n, status


@dataclass
class OfflineRun:
    scenario: str
    seed: int
    truth: np.ndarray  # [t, x, y, yaw, speed] of base_link, ground-truth rate
    antenna: np.ndarray  # [t, true e, true n, fix e, fix n, var_e, var_n, status, multipath, drift e, drift n]
    #                      every GPS epoch (the drift: the receiver's own, in the fix, never published)
    estimate: np.ndarray  # [t, x, y, theta, cov_xx, cov_xy, cov_yy, cov_thth]: every keyframe
    calibration: Dict[str, float]
    counters: Dict[str, int]
    diagnostics: List[Tuple[float, str]]  # (time, message) of every fault the smoother raised
    update_ms: np.ndarray  # wall time of each smoother update [ms]
    cpu_frac: float  # smoother wall time over sim time
    wall: float  # [s] the whole run
    end_reason: str
    inputs: Inputs
    truth_calibration: Dict[str, float]  # what the smoother should find (from the scenario's sim section)
    update_cpu_ms: np.ndarray = field(default_factory=lambda: np.zeros(0))  # CPU time of each update [ms]


def _sim_params(s: Scenario, seed: int):
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.simulator import SimParams

    p = _defaults(SimParams, package_file("config", "sim.yaml"))
    over = _section(s.data, "sim")
    if over:
        p = replace_nested(p, over, f"{s.path}: sim")
    return replace_nested(p, {"seed": seed})


def sensor_params(s: Scenario, sensor: str, cls, cfg: str):
    """A sensor adapter's parameters in scenario ``s``: its config file with the scenario's overrides."""
    from quadrivio_sim.paths import package_file

    p = _defaults(cls, package_file("config", cfg))
    over = _section(s.data, f"sensors/{sensor}")
    return replace_nested(p, over, f"{s.path}: sensors.{sensor}") if over else p


def localizer_params(s: Optional[Scenario], mag_calibration: Optional[str] = "default"):
    """The localization node's parameters for scenario ``s``: localization.yaml, then the
    magnetometer calibration file (``"default"``: the simulated magnetometer's, as
    sim.launch loads; ``None`` or ``""``: none), then the scenario's section."""
    import dataclasses

    from quadrivio_description.paths import ros_package_path
    from quadrivio_localization.smoother import LocalizerParams
    from quadrivio_sim.paths import package_file

    cfg = ros_package_path("quadrivio_localization") + "/config/localization.yaml"
    p = _defaults(LocalizerParams, cfg)
    if mag_calibration == "default":
        mag_calibration = package_file("config", "mag_calibration.yaml")
    if mag_calibration:
        data = load_yaml(mag_calibration)
        names = {f.name for f in dataclasses.fields(LocalizerParams)}
        p = replace_nested(p, {k: v for k, v in data.items() if k in names}, mag_calibration)
    over = _section(s.data, "localization") if s is not None else None
    return replace_nested(p, over, f"{s.path}: localization") if over else p


def _route(s: Scenario, start: Tuple[float, float, float]):
    from quadrivio_navigation.follower import FollowerConfig, make_route
    from quadrivio_navigation.paths import PathParams, path_points

    from quadrivio_description.paths import ros_package_path

    nav = ros_package_path("quadrivio_navigation")
    pp = _defaults(PathParams, nav + "/config/path.yaml")
    fp = _defaults(FollowerConfig, nav + "/config/follower.yaml")
    if _section(s.data, "path"):
        pp = replace_nested(pp, _section(s.data, "path"), f"{s.path}: path")
    if _section(s.data, "follower"):
        fp = replace_nested(fp, _section(s.data, "follower"), f"{s.path}: follower")
    if pp.kind == "goal":
        raise ConfigError(f"{s.path}: path kind 'goal' needs the planner: run it closed loop (experiment)")
    c, sn = math.cos(start[2]), math.sin(start[2])
    waypoints = [(start[0] + c * x - sn * y, start[1] + sn * x + c * y) for x, y in pp.waypoints]
    pts = path_points(pp.kind, start, pp.figure_eight, waypoints, pp.ds)
    heading = np.arctan2(np.gradient(pts[:, 1]), np.gradient(pts[:, 0]))
    route = make_route(np.column_stack([pts, heading]), fp.profile, fp.pure_pursuit.reverse_speed)
    return route, fp


def truth_calibration(sim_params, mag_noise) -> Dict[str, float]:
    """The calibration the smoother should converge to, in its own conventions."""
    m = sim_params.measurement
    return {"wheel_speed_scale": 1.0 / m.wheel_speed_scale, "handlebar_offset": m.handlebar_offset,
            "mag_hard_iron_x": mag_noise.hard_iron[0] * 1e6, "mag_hard_iron_y": mag_noise.hard_iron[1] * 1e6}


def run(s: Scenario, seed: int, localizer_factory: Optional[Callable] = None, mag_calibration: Optional[str] = "default",
        progress: Optional[Callable[[float, float], None]] = None, record_inputs: bool = True) -> OfflineRun:
    """Run scenario ``s`` with ``seed`` (see module docstring). ``localizer_factory(params,
    vehicle, site)`` builds the smoother (default: :class:`Localizer`); ``progress(t,
    t_end)`` is called every simulated second."""
    from quadrivio_description.site import load_site
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_localization.smoother import Localizer
    from quadrivio_navigation.follower import ABORTED, DONE, PurePursuit
    from quadrivio_plc import protocol
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.adapter_params import GpsAdapterParams, ImuAdapterParams, MagAdapterParams
    from quadrivio_sim.noise import sensor_models
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.simulator import Simulator
    from quadrivio_sim.world import quat_to_rpy

    wall0 = time.perf_counter()
    v, site = scenario_vehicle(s, load_vehicle()), load_site()
    frame = site.local_frame()
    sp = _sim_params(s, seed)
    sim = Simulator(sp, v, load_actuators(package_file("config", "actuators.yaml")), build_urdf(v), site)
    for name in ("scan", "image", "joint_states"):
        if name in sim.enabled:
            sim.enabled[name] = False
    gp = sensor_params(s, "gps", GpsAdapterParams, "gps.yaml")
    ip = sensor_params(s, "imu", ImuAdapterParams, "imu.yaml")
    mp = sensor_params(s, "mag", MagAdapterParams, "mag.yaml")
    # the adapters' own models, from the same factory and generators as theirs
    gps, gps_lat = sensor_models("gps", gp, seed, GPS_NODE)
    imu, imu_lat = sensor_models("imu", ip, seed, IMU_NODE)
    mag, mag_lat = sensor_models("mag", mp, seed, MAG_NODE)
    lp = localizer_params(s, mag_calibration)
    loc = (localizer_factory or Localizer)(lp, v, site)
    spawn = sp.spawn
    route, fp = _route(s, (spawn.x, spawn.y, spawn.yaw))
    pp = PurePursuit(fp.pure_pursuit, route, v, 0.0, 0.0, None)
    pp.set_limits(fp.profile.accel, fp.profile.decel)
    follow_steps = max(1, int(round(1.0 / (fp.rate * sim.dt))))
    loc_steps = max(1, int(round(1.0 / (lp.rate * sim.dt))))
    t_end = s.run.max_duration
    queue: List[Tuple[float, int, str, tuple]] = []  # (delivery, order, kind, data)
    order = 0
    inputs = Inputs()
    truth, antenna, estimate, update_ms, diagnostics = [], [], [], [], []
    update_cpu_ms: List[float] = []  # the same updates' CPU time (wall time counts waiting for a core too)
    gt = None
    end_reason = "max_duration"
    done_at: Optional[float] = None
    smoother_wall = 0.0
    restarts = 0
    last_diag = ""
    sim.plc.force_auto(0.0)

    def push(deliver: float, kind: str, data: tuple) -> None:
        nonlocal order
        heapq.heappush(queue, (deliver, order, kind, data))
        order += 1

    while sim.t < t_end - 1e-9:
        if sim.steps % follow_steps == 0 and gt is not None:
            yaw = quat_to_rpy(gt.orientation)[2]
            c = math.cos(yaw)
            speed = gt.linear_velocity[0] * c + gt.linear_velocity[1] * math.sin(yaw)
            cmd = pp.update(gt.position[0], gt.position[1], yaw, speed, 0.0, sim.t)
            sim.plc.setpoint(protocol.SOURCE_AUTO, cmd.speed, cmd.handlebar, cmd.brake, sim.t)
            if pp.status in (DONE, ABORTED) and done_at is None:
                done_at = sim.t
                end_reason = "path_done" if pp.status == DONE else f"aborted: {cmd.reason}"
        for name, x in sim.step():
            if name == "ground_truth":
                gt = x
                yaw = quat_to_rpy(x.orientation)[2]
                truth.append((x.stamp, x.position[0], x.position[1], yaw,
                              x.linear_velocity[0] * math.cos(yaw) + x.linear_velocity[1] * math.sin(yaw)))
            elif name == "plc_state":  # the PLCClient relays STATE frames at once (sub-millisecond on loopback)
                push(x.plc_time, "state", (x.plc_time, x.wheel_speed, x.handlebar))
            elif name == "imu":
                f, w = imu.apply(x.specific_force, x.angular_rate)
                push(imu_lat.deliver_at(x.stamp), "imu", (x.stamp, *map(float, f), *map(float, w)))
            elif name == "mag":
                m = mag.apply(x.field)
                push(mag_lat.deliver_at(x.stamp), "mag", (x.stamp, *map(float, m)))
            elif name == "gps":
                r = gps.apply(x.stamp, x.position, x.velocity)
                if r.position is None:
                    data = (x.stamp, math.nan, math.nan, math.nan, math.nan, math.nan, r.status)
                    antenna.append((x.stamp, x.position[0], x.position[1], math.nan, math.nan, math.nan, math.nan,
                                    r.status, 0) + r.drift)
                else:
                    lat, lon, alt = frame.enu_to_lla(*r.position)
                    data = (x.stamp, lat, lon, alt, r.variances[0], r.variances[1], r.status)
                    antenna.append((x.stamp, x.position[0], x.position[1], r.position[0], r.position[1],
                                    r.variances[0], r.variances[1], r.status, int(r.multipath)) + r.drift)
                push(gps_lat.deliver_at(x.stamp), "gps", data)
        t = sim.t
        while queue and queue[0][0] <= t + 1e-9:
            deliver, _, kind, data = heapq.heappop(queue)
            if kind == "state":
                loc.add_vehicle_state(*data)
            elif kind == "imu":
                loc.add_imu(data[0], data[1:4], data[4:7])
            elif kind == "mag":
                loc.add_mag(data[0], data[1:4])
            else:
                loc.add_gps(*data)
            if record_inputs:
                getattr(inputs, kind).append((deliver,) + tuple(data))
        if sim.steps % loc_steps == 0:
            w0, c0 = time.perf_counter(), time.thread_time()
            try:
                e = loc.update(t)
            except RuntimeError as exc:  # as the node does: a numerically failed update restarts the smoother
                diagnostics.append((t, f"smoother update failed ({str(exc).strip().splitlines()[0]}): restarted"))
                restarts += 1
                loc = (localizer_factory or Localizer)(lp, v, site)
                e = None
            dt_wall = time.perf_counter() - w0
            smoother_wall += dt_wall
            update_ms.append(dt_wall * 1e3)
            update_cpu_ms.append((time.thread_time() - c0) * 1e3)
            if e is not None and (not estimate or e.stamp > estimate[-1][0]):
                c = e.covariance
                estimate.append((e.stamp, e.x, e.y, e.theta, c[0, 0], c[0, 1], c[1, 1], c[2, 2]))
            faults = getattr(loc, "faults", None)
            text = "; ".join(faults()) if callable(faults) else ""
            if text and text != last_diag:
                diagnostics.append((t, text))
            last_diag = text
        if progress is not None and sim.steps % 100 == 0:
            progress(t, t_end)
        if done_at is not None and s.run.end == "path_done" and t - done_at >= 2.0:
            break
    sim.close()
    est = loc._estimate() if hasattr(loc, "_estimate") else None
    calibration = dict(est.calibration) if est is not None else {}
    counters = dict(vars(loc.counters)) if hasattr(loc, "counters") else {}
    counters["restarts"] = restarts
    gate = getattr(loc, "gate", None)
    if gate is not None:
        counters["gps_not_used"] = {k: v for k, v in gate.counts.items() if v}
        counters["gps_accepted_after_yield"] = gate.yielded
    return OfflineRun(s.name, seed, np.array(truth), np.array(antenna), np.array(estimate).reshape(-1, 8),
                      calibration, counters, diagnostics, np.array(update_ms), smoother_wall / max(sim.t, 1e-9),
                      time.perf_counter() - wall0, end_reason, inputs, truth_calibration(sp, mp.noise),
                      np.array(update_cpu_ms))


# ------------------------------------------------------------------ scoring
def _wrap(a):
    return (np.asarray(a) + np.pi) % (2.0 * np.pi) - np.pi


def errors(r: OfflineRun) -> np.ndarray:
    """[t, position error, heading error (rad), error east, error north] at every keyframe."""
    if len(r.estimate) == 0:
        return np.zeros((0, 5))
    tt = r.truth[:, 0]
    t = r.estimate[:, 0]
    inside = (t >= tt[0]) & (t <= tt[-1])
    e = r.estimate[inside]
    x = np.interp(e[:, 0], tt, r.truth[:, 1])
    y = np.interp(e[:, 0], tt, r.truth[:, 2])
    yaw = np.interp(e[:, 0], tt, np.unwrap(r.truth[:, 3]))
    ex, ey = e[:, 1] - x, e[:, 2] - y
    return np.column_stack([e[:, 0], np.hypot(ex, ey), _wrap(e[:, 3] - yaw), ex, ey])


def rmse(x) -> float:
    x = np.asarray(x, float)
    return float(np.sqrt(np.mean(np.square(x)))) if len(x) else math.nan


def oracle_rms(r: OfflineRun, s: Scenario, settle: float = SETTLE) -> float:
    """RMS position error after ``settle`` s of the GNSS oracle (:mod:`quadrivio.gnss_bound`)
    on this run's fixes, with the scenario's receiver model; multipath fixes are known to it
    and left out. NaN without fixes or without the drift in the run's record."""
    from quadrivio_sim.adapter_params import GpsAdapterParams

    from .gnss_bound import oracle_errors

    a = r.antenna
    if len(a) == 0 or a.shape[1] < 11:
        return math.nan
    noise = sensor_params(s, "gps", GpsAdapterParams, "gps.yaml").noise
    std2, drift2 = noise.horizontal_std ** 2, noise.drift.sigma ** 2
    has = (a[:, 7] >= 0) & np.isfinite(a[:, 3]) & np.isfinite(a[:, 5])
    offsets = np.where(has[:, None], a[:, 3:5] - a[:, 1:3], np.nan)
    # the reported variance is (white + drift) x the degradation factor squared; the white part:
    white = np.where(has, a[:, 5] * (std2 / (std2 + drift2) if std2 + drift2 > 0 else 0.0), np.nan)
    e = oracle_errors(a[:, 0], offsets, white, noise.drift.sigma, noise.drift.tau, a[:, 8] == 0)
    late = e[(a[:, 0] >= settle) & np.all(np.isfinite(e), axis=1)]
    return rmse(np.hypot(late[:, 0], late[:, 1])) if len(late) else math.nan


def score(r: OfflineRun, s: Scenario, settle: float = SETTLE) -> Dict[str, object]:
    """The run's figures (see ``campaign``): errors after ``settle`` s, the raw GPS's and its
    drift's alone, the
    calibration found against the truth, and per scheduled outage the error at its end and
    10 s later."""
    err = errors(r)
    late = err[err[:, 0] >= settle]
    a = r.antenna
    fixes = a[(a[:, 0] >= settle) & (a[:, 7] >= 0)] if len(a) else a
    gps_err = np.hypot(fixes[:, 3] - fixes[:, 1], fixes[:, 4] - fixes[:, 2]) if len(fixes) else np.zeros(0)
    out: Dict[str, object] = {
        "scenario": r.scenario, "seed": r.seed, "end": r.end_reason, "duration": float(r.truth[-1, 0]),
        "rmse_m": rmse(late[:, 1]), "max_error_m": float(late[:, 1].max()) if len(late) else math.nan,
        "heading_rmse_deg": math.degrees(rmse(late[:, 2])),
        "gps_rmse_m": rmse(gps_err),
        # the receiver's slow drift alone, at every epoch: no GNSS-only estimate can see it,
        # so it is a floor for the position error (not a bound: odometry can see some of it)
        "gps_drift_rms_m": rmse(np.hypot(*a[a[:, 0] >= settle][:, 9:11].T)) if len(a) and a.shape[1] >= 11
        else math.nan,
        # the best any causal estimator can do in expectation: perfect odometry and the
        # receiver's true drift model (quadrivio.gnss_bound; the EKF scores the drift's)
        "gps_oracle_rms_m": oracle_rms(r, s, settle),
        "update_p99_ms": float(np.percentile(r.update_ms, 99)) if len(r.update_ms) else math.nan,
        "update_cpu_p99_ms": float(np.percentile(r.update_cpu_ms, 99)) if len(r.update_cpu_ms) else math.nan,
        "cpu_frac": r.cpu_frac, "wall_s": r.wall,
        "counters": r.counters,
    }
    c, tc = r.calibration, r.truth_calibration
    if c:
        out["steer_offset_error_deg"] = math.degrees(c["handlebar_offset"] - tc["handlebar_offset"])
        out["wheel_scale_error_pct"] = 100.0 * (c["wheel_speed_scale"] / tc["wheel_speed_scale"] - 1.0)
    outages = []
    gps_noise = _section(s.data, "sensors/gps/noise/outages/scheduled") or []
    for start, end in gps_noise:
        def at(t0):
            i = np.searchsorted(err[:, 0], t0)
            return float(err[min(i, len(err) - 1), 1]) if len(err) else math.nan
        outages.append({"start": float(start), "end": float(end), "error_at_end_m": at(end),
                        "error_10s_after_m": at(end + 10.0)})
    if outages:
        out["outages"] = outages
    dead = _section(s.data, "sim/measurement/wheel_speed_dead") or []
    if dead:
        start = float(dead[0][0])
        named = [t for t, text in r.diagnostics if t >= start and "wheel" in text]
        out["dead_wheel_named_after_s"] = (named[0] - start) if named else None
    return out
