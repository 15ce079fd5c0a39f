"""Sim-to-real actuator calibration: identify the PLC loops from recorded responses.

The paper tuned the simulator's handlebar and speed loops by hand until their step
responses matched the real vehicle's (section 3.2, Fig. 4). Here that is a fit:
recorded setpoints drive the loop models of :mod:`quadrivio_sim.actuators` and the
free parameters minimise the RMS error between simulated and measured responses
(``scipy.optimize.least_squares``). The dead time is searched on whole PLC cycles (a
coarse grid from 0 to ``MAX_DEAD_TIME``, then every cycle around the best): once a
loop is rate- or ramp-limited, a fraction of a cycle changes nothing and the dead time
has no gradient.

* Handlebar: ``kp`` (bandwidth), ``servo_tau`` (second order; 0 = first order),
  ``max_rate`` and ``dead_time``; ``max_angle`` when the recording saturates. Both orders
  are fitted; the second is kept only if it lowers the RMS error by more than 5 %.
* Speed: the loop (ramp limits ``max_accel`` / ``max_decel``, ``engine_brake``,
  ``dead_time``) around a point-mass model of the vehicle (mass with wheel inertia,
  rolling resistance, disc brakes as Coulomb friction) -- a fast stand-in for the full
  simulation, which then replays the recording for validation.

A parameter the recording does not excite is reported (relative standard error of the
fit above ``MAX_RELATIVE_SE``), with what the recording would need; nothing is written.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Sequence

import numpy as np
from scipy.optimize import least_squares

from quadrivio_config import replace_nested
from quadrivio_description.vehicle import GRAVITY, VehicleParams

from .actuators import ActuatorParams, HandlebarLoop, HandlebarLoopParams, SpeedLoop, SpeedLoopParams, StepReference

MAX_RELATIVE_SE = 0.2  # a fitted parameter with a larger relative standard error is not identified
MAX_DEAD_TIME = 0.3  # [s] longest dead time searched


class CalibrationError(ValueError):
    """The recording cannot support the calibration (missing data, too little excitation)."""


@dataclass
class Series:
    """A loop's recording on a uniform grid of the PLC cycle."""
    t: np.ndarray  # [s]
    setpoint: np.ndarray
    measured: np.ndarray
    brake: np.ndarray  # [1] brake setpoint (zeros for the handlebar)

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def recording_warnings(loop: str, s: Series, vehicle: VehicleParams) -> List[str]:
    """What makes a recording's step metrics meaningless, in words: setpoints beyond the
    vehicle's limits (a unit mismatch: degrees for radians, km/h for m/s), or a measurement
    that moves a small fraction of what the setpoints ask (setpoint and measurement in
    different units or scales)."""
    out = []
    sp, ms = np.asarray(s.setpoint, float), np.asarray(s.measured, float)
    if not len(sp):
        return out
    if loop == "handlebar":
        limit_lo, limit_hi, unit = -vehicle.steering.max_angle, vehicle.steering.max_angle, "rad"
    else:
        limit_lo, limit_hi, unit = -vehicle.drivetrain.max_reverse_speed, vehicle.drivetrain.max_speed, "m/s"
    beyond = (sp > limit_hi * 1.05) | (sp < limit_lo * 1.05 - 1e-9)
    if beyond.mean() > 0.01:
        out.append(f"the {loop} setpoints reach {float(sp.min()):.3g} .. {float(sp.max()):.3g} {unit}, beyond the "
                   f"vehicle's limits ({limit_lo:g} .. {limit_hi:g} {unit}) {100 * beyond.mean():.0f} % of the time: "
                   f"likely a unit mismatch (the mapping's setpoint scale)")
    sp_range = float(np.percentile(sp, 95) - np.percentile(sp, 5))
    ms_range = float(np.percentile(ms, 95) - np.percentile(ms, 5)) if len(ms) else 0.0
    if sp_range > 0.0 and ms_range < 0.2 * sp_range:
        out.append(f"the measured {loop} moves {ms_range:.3g} {unit} where its setpoints move {sp_range:.3g} "
                   f"{unit} ({ms_range / sp_range:.2g} of it): setpoint and measurement are likely in different "
                   f"units or scales, and the step metrics below compare them as they are")
    return out


def resample(t_src: np.ndarray, values: np.ndarray, t_grid: np.ndarray, hold: bool) -> np.ndarray:
    """Values at ``t_grid``: zero-order hold (setpoints) or linear interpolation (measurements)."""
    if hold:
        idx = np.clip(np.searchsorted(t_src, t_grid, side="right") - 1, 0, len(t_src) - 1)
        return values[idx]
    return np.interp(t_grid, t_src, values)


def make_series(t_sp: np.ndarray, sp: np.ndarray, t_meas: np.ndarray, meas: np.ndarray, dt: float,
                brake: Optional[np.ndarray] = None) -> Series:
    """Both signals on one grid over the span where both exist."""
    t0, t1 = max(t_sp[0], t_meas[0]), min(t_sp[-1], t_meas[-1])
    if t1 - t0 < 20 * dt:
        raise CalibrationError(f"setpoints and measurements overlap for only {max(0.0, t1 - t0):.2f} s")
    grid = np.arange(t0, t1, dt)
    b = resample(t_sp, brake, grid, True) if brake is not None else np.zeros_like(grid)
    return Series(grid, resample(t_sp, sp, grid, True), resample(t_meas, meas, grid, False), b)


# ------------------------------------------------------------------ models

def simulate_handlebar(p: HandlebarLoopParams, vehicle: VehicleParams, s: Series) -> np.ndarray:
    """The loop's response to the recorded setpoint."""
    loop = HandlebarLoop(p, vehicle, s.dt)
    loop.reset(float(s.measured[0]))
    step = loop.step
    return np.fromiter((step(float(x)) for x in s.setpoint), float, len(s.setpoint))


class LongitudinalModel:
    """The vehicle along its path as a point mass on its wheels (the fit's stand-in).

    ``m_e v' = (T_drive - T_rr) / r - brake``, with ``m_e = m + 4 I_w / r^2`` (wheel
    inertia ``I_w = m_w r^2 / 2``), rolling resistance ``T_rr = Crr m g r tanh(v / (0.5 r))``
    and the brake a Coulomb friction of at most ``T_brake / r`` (it holds the vehicle still).
    """

    def __init__(self, vehicle: VehicleParams, rolling_resistance: float, dt: float) -> None:
        r = vehicle.wheel_radius
        self.r = r
        self.m = vehicle.body.mass + 4.0 * 0.5 * vehicle.wheels.mass  # + 4 I_w / r^2
        self.rr = rolling_resistance * vehicle.body.mass * GRAVITY
        self.dt = dt
        self.v = 0.0

    def step(self, drive_torque: float, brake_torque: float) -> float:
        f = drive_torque / self.r - self.rr * math.tanh(self.v / (0.5 * self.r))
        fb = brake_torque / self.r
        v = self.v
        if v == 0.0 and abs(f) <= fb:
            return 0.0
        v_new = v + (f - math.copysign(fb, v if v != 0.0 else f)) / self.m * self.dt
        self.v = 0.0 if v != 0.0 and v_new * v < 0.0 else v_new
        return self.v


def simulate_speed(p: SpeedLoopParams, vehicle: VehicleParams, rolling_resistance: float, s: Series) -> np.ndarray:
    """The loop and the point-mass vehicle driven by the recorded setpoints."""
    loop = SpeedLoop(p, vehicle, s.dt)
    plant = LongitudinalModel(vehicle, rolling_resistance, s.dt)
    plant.v = float(s.measured[0])
    loop.ramp = plant.v
    out = np.empty(len(s.t))
    r = vehicle.wheel_radius
    for k, (sp, b) in enumerate(zip(s.setpoint, s.brake)):
        drive, brake = loop.step(float(sp), float(b), plant.v, plant.v / r)
        out[k] = plant.step(drive, brake)
    return out


# ------------------------------------------------------------------ steps

@dataclass
class Step:
    t0: float  # [s] when the setpoint jumped
    t1: float  # [s] end of the segment (next jump or end of data)
    start: float  # setpoint before
    end: float  # setpoint after


def find_steps(s: Series, min_step: float, min_hold: float) -> List[Step]:
    """Setpoint jumps of at least ``min_step`` held for at least ``min_hold`` seconds."""
    jumps = np.flatnonzero(np.abs(np.diff(s.setpoint)) >= min_step) + 1
    edges = list(jumps) + [len(s.t) - 1]
    steps = []
    for a, b in zip(edges[:-1], edges[1:]):
        if s.t[b] - s.t[a] >= min_hold:
            steps.append(Step(float(s.t[a]), float(s.t[b]), float(s.setpoint[a - 1]), float(s.setpoint[a])))
    return steps


@dataclass
class StepMetrics:
    delay: float  # [s] from the jump to 10 % of the step
    rise_time: float  # [s] 10 % to 90 %
    overshoot: float  # [1] fraction of the step beyond the final value


def step_metrics(t: np.ndarray, y: np.ndarray, step: Step) -> Optional[StepMetrics]:
    m = (t >= step.t0) & (t < step.t1)
    if m.sum() < 5:
        return None
    tt, yy = t[m] - step.t0, y[m]
    y0 = float(y[max(0, np.argmax(m) - 1)])
    amp = step.end - y0
    if abs(amp) < 1e-9:
        return None
    f = (yy - y0) / amp
    if f.max() < 0.9:
        return None
    t10 = float(tt[np.argmax(f >= 0.1)])
    t90 = float(tt[np.argmax(f >= 0.9)])
    return StepMetrics(t10, t90 - t10, max(0.0, float(f.max()) - 1.0))


def mean_metrics(metrics: Sequence[Optional[StepMetrics]]) -> Optional[StepMetrics]:
    ok = [m for m in metrics if m is not None]
    if not ok:
        return None
    return StepMetrics(*(float(np.mean([getattr(m, f.name) for m in ok])) for f in dataclasses.fields(StepMetrics)))


# ------------------------------------------------------------------ fitting

@dataclass
class Fit:
    loop: str
    values: Dict[str, float]  # identified parameter -> value
    std_errors: Dict[str, float]
    rms: float  # response RMS error of the fit
    noise: float  # residual standard deviation estimate
    notes: List[str] = field(default_factory=list)


HINTS = {
    "pid.kp": "small handlebar steps that the rate limit does not cut (< 0.1 rad)",
    "servo_tau": "handlebar steps sampled fast enough to show the servo's lag (>= 50 Hz)",
    "max_rate": "large handlebar steps (> 0.2 rad) that the servo takes at its rate limit",
    "dead_time": "clean steps with the setpoint and the measurement on one clock",
    "max_accel": "speed steps up of at least 1 m/s",
    "max_decel": "speed steps down of at least 1 m/s with the brake released",
    "engine_brake": "coasting: small speed decreases (0.2 - 0.5 m/s) at a few m/s, brake released",
}


def _noise_floor(s: Series) -> float:
    """Measurement noise from the high-pass residual of the measurement (MAD of 2nd differences)."""
    d2 = np.diff(s.measured, 2)
    return float(1.4826 * np.median(np.abs(d2 - np.median(d2))) / math.sqrt(6.0))


def _least_squares(residual: Callable[[np.ndarray], np.ndarray], x0: Sequence[float], lo: Sequence[float],
                   hi: Sequence[float]):
    return least_squares(residual, np.asarray(x0, float), bounds=(np.asarray(lo, float), np.asarray(hi, float)),
                         x_scale="jac", diff_step=1e-3, max_nfev=200)


def _standard_errors(res, n_free: int) -> np.ndarray:
    J = res.jac
    dof = max(1, J.shape[0] - n_free)
    s2 = 2.0 * res.cost / dof
    try:
        cov = np.linalg.inv(J.T @ J) * s2
        return np.sqrt(np.clip(np.diag(cov), 0.0, None))
    except np.linalg.LinAlgError:
        return np.full(n_free, np.inf)


def _fit_with_dead_time(make: Callable[[np.ndarray, float], np.ndarray], measured: np.ndarray,
                        x0: Sequence[float], lo: Sequence[float], hi: Sequence[float], dt: float):
    """Least squares over the loop's parameters for each dead time of a grid of whole
    cycles (coarse, then every cycle around the best); returns ``(dead_time, result)``."""
    n_max = int(round(MAX_DEAD_TIME / dt))
    coarse = max(1, n_max // 10)
    tried = {}

    def fit(n: int):
        if n not in tried:
            tried[n] = _least_squares(lambda x: make(x, n * dt) - measured, x0, lo, hi)
        return tried[n]

    best = min(range(0, n_max + 1, coarse), key=lambda n: fit(n).cost)
    best = min(range(max(0, best - coarse + 1), min(n_max, best + coarse - 1) + 1), key=lambda n: fit(n).cost)
    return best * dt, tried[best]


def identify_handlebar(s: Series, vehicle: VehicleParams, base: HandlebarLoopParams) -> Fit:
    dt = s.dt
    if np.ptp(s.setpoint) < 0.05:
        raise CalibrationError("the handlebar setpoint hardly changes (less than 0.05 rad): "
                               "the recording needs handlebar steps, small and large")
    noise = _noise_floor(s)
    peak = float(np.max(np.abs(s.measured)))
    saturates = float(np.max(np.abs(s.setpoint))) > peak + max(0.02, 3 * noise)
    if saturates:  # a first guess of the stop (then fitted): median while the setpoint is beyond it
        beyond = np.abs(s.setpoint) > peak + max(0.02, 3 * noise)
        settled = beyond & (np.abs(np.diff(s.measured, prepend=s.measured[0])) < 3 * noise + 1e-9)
        max_angle = float(np.median(np.abs(s.measured[settled if settled.any() else beyond])))
    else:
        max_angle = base.max_angle or vehicle.steering.max_angle

    def params(x: np.ndarray, second: bool, d: float = 0.0) -> HandlebarLoopParams:
        return replace_nested(base, {"pid": {"kp": float(x[0]), "ki": 0.0}, "max_rate": float(x[1]),
                                     "servo_tau": float(x[2]) if second else 0.0, "dead_time": d,
                                     "max_angle": float(x[-1]) if saturates else max_angle}, "fit")

    fits = {}
    for second in (False, True):
        names = ["pid.kp", "max_rate"] + (["servo_tau"] if second else []) + (["max_angle"] if saturates else [])
        x0 = [4.0, vehicle.steering.max_rate] + ([0.05] if second else []) + ([max_angle] if saturates else [])
        lo = [0.2, 0.02] + ([0.0] if second else []) + ([0.5 * max_angle] if saturates else [])
        hi = [50.0, 10.0] + ([1.0] if second else []) + ([min(1.5, 1.5 * max_angle)] if saturates else [])
        fits[second] = (names,) + _fit_with_dead_time(
            lambda x, d: simulate_handlebar(params(x, second, d), vehicle, s), s.measured, x0, lo, hi, dt)
    rms_of = {k: math.sqrt(2.0 * v[2].cost / len(s.t)) for k, v in fits.items()}
    second = rms_of[True] < 0.95 * rms_of[False]
    names, d, res = fits[second]
    se = _standard_errors(res, len(names))
    values = dict(zip(names, map(float, res.x)))
    values["dead_time"] = d
    std = dict(zip(names, map(float, se)))
    fit = Fit("handlebar", values, std, rms_of[second], noise,
              [f"{'second' if second else 'first'}-order servo (RMS {rms_of[True]:.4f} vs {rms_of[False]:.4f} rad "
               f"for second / first order)", f"max_angle {'identified from saturation' if saturates else 'not excited'}"])
    _check_excitation(fit, exclude=("dead_time",))
    return fit


def identify_speed(s: Series, vehicle: VehicleParams, base: SpeedLoopParams, rolling_resistance: float) -> Fit:
    dt = s.dt
    if np.ptp(s.setpoint) < 0.5:
        raise CalibrationError("the speed setpoint hardly changes (less than 0.5 m/s): "
                               "the recording needs speed steps up and down")
    noise = _noise_floor(s)
    names = ["max_accel", "max_decel", "engine_brake"]

    def params(x: np.ndarray, d: float) -> SpeedLoopParams:
        return replace_nested(base, {"max_accel": float(x[0]), "max_decel": float(x[1]),
                                     "engine_brake": float(x[2]), "dead_time": d}, "fit")

    d, res = _fit_with_dead_time(lambda x, d: simulate_speed(params(x, d), vehicle, rolling_resistance, s),
                                 s.measured, [1.5, 2.0, 6.0], [0.1, 0.1, 0.0], [10.0, 15.0, 200.0], dt)
    values = dict(zip(names, map(float, res.x)))
    values["dead_time"] = d
    std = dict(zip(names, map(float, _standard_errors(res, len(names)))))
    fit = Fit("speed", values, std, math.sqrt(2.0 * res.cost / len(s.t)), noise)
    _check_excitation(fit, exclude=("dead_time",))
    return fit


def _check_excitation(fit: Fit, exclude: Sequence[str] = ()) -> None:
    missing = []
    for name, value in fit.values.items():
        if name in exclude:
            continue
        se = fit.std_errors.get(name, 0.0)
        rel = se / abs(value) if value else math.inf
        if not math.isfinite(rel) or rel > MAX_RELATIVE_SE:
            missing.append(f"{fit.loop}.{name} (relative standard error {rel:.0%}): the recording needs "
                           f"{HINTS.get(name, 'more excitation')}")
    if missing:
        raise CalibrationError("too little excitation to identify " + "; ".join(missing))


def apply_fits(base: ActuatorParams, fits: Sequence[Fit],
               references: Dict[str, Optional[StepReference]]) -> ActuatorParams:
    """``base`` with the identified values and the measured step responses as references."""
    changes: Dict[str, Dict] = {}
    for f in fits:
        section: Dict = changes.setdefault(f.loop, {})
        for name, value in f.values.items():
            node = section
            *path, leaf = name.split(".")
            for p in path:
                node = node.setdefault(p, {})
            node[leaf] = round(value, 6)
    out = replace_nested(base, changes, "calibration")
    return dataclasses.replace(out, handlebar_reference=references.get("handlebar") or base.handlebar_reference,
                               speed_reference=references.get("speed") or base.speed_reference)


def reference_from(steps: List[Step], metrics: List[Optional[StepMetrics]]) -> Optional[StepReference]:
    """The recorded vehicle's typical step (the largest clean one) as a StepReference."""
    pairs = [(s, m) for s, m in zip(steps, metrics) if m is not None and abs(s.start) < 1e-6]
    if not pairs:
        pairs = [(s, m) for s, m in zip(steps, metrics) if m is not None]
    if not pairs:
        return None
    s, m = max(pairs, key=lambda p: abs(p[0].end - p[0].start))
    return StepReference(step=round(s.end - s.start, 4), rise_time=round(m.rise_time, 4), rise_time_tol=0.2,
                         max_overshoot=round(max(0.05, 1.5 * m.overshoot), 4))


def rms(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.sqrt(np.mean((np.asarray(a) - np.asarray(b)) ** 2)))


