"""The low-level loops the vehicle's PLC runs: handlebar position and speed (paper section 3.2).

Both loops are PID controllers closed around a servo model, stepped at the PLC cycle.
The simulator does not model the steering column or the engine in detail; instead,
as in the paper, the loops are modelled so that their step responses match the real
vehicle's (Fig. 4). Their parameters are the ones ``calibrate`` identifies from bags.

Handlebar (position servo)::

    s_d(t)  = s(t - T_d)                             dead time T_d of the command path
    u       = clip(PID(clip(s_d, +-h_max) - h), +-r_max)   rate command [rad/s]
    w'      = (u - w) / tau_h                         servo velocity lag tau_h
    h'      = w,  h in [-h_max, h_max] (mechanical stops)

Speed (throttle/brake servos, torque at the wheels)::

    r'      = clip((v_sp - r) / dt, -a_dec, a_acc),  r in [v - b, v + b]   setpoint ramp (0: no limit)
    u       = clip(u_ff + PID(r - v), -1, 1),  u_ff = f_0 + f_1 |r| + f_a r'  (f_0 only while r != 0)
    throttle_cmd = max(u, 0) (1 - b_sp),  brake_cmd = max(b_sp, k_b * max(-u - d_b, 0))
    e_over = outside(sgn(v_sp) v, [-m_r, max(|v_sp|, |r_free|) + m_o])           runaway guard
    e_over > 0:  throttle_cmd = 0,  brake_cmd = 1 against the command, else max(brake_cmd, k_o e_over)
    throttle' = (throttle_cmd - throttle) / tau_t,  brake' = (brake_cmd - brake) / tau_b
    T_drive = gear * throttle * T_max  -  c_eb * (1 - throttle) * w_wheel     (engine braking)
    T_brake = brake * B_max                                                  (opposes rotation)

The feedforward ``u_ff`` is the PLC's throttle for a speed on flat ground (rolling
resistance and engine braking: ``f_0 + f_1 |r|``) and for the ramp's acceleration
(``f_a r'``, ideally ``m r_w / T_max``), so the PID only corrects small errors and its
integral handles what is left (slopes, load) without winding up. The engine-braking term
``c_eb`` is what makes deceleration differ from acceleration when the throttle is
suddenly closed (the mismatch of the paper's Fig. 4b).

The runaway guard is what a real PLC adds to the loop: the ramp follows the vehicle
within ``b`` (it waits for a vehicle that cannot keep up), so on a steep slope the PID
alone sees only a small error while the vehicle rolls back or runs away downhill. The
guard compares the speed along the commanded direction with the command itself and
with ``r_free``, the same ramp without the band (how fast the vehicle may still be
while it slows down as commanded): moving against the command by more than ``m_r``
closes the throttle and brakes fully; faster than both by more than ``m_o`` closes the
throttle and brakes in proportion.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Deque, Optional, Tuple

from quadrivio_config import param
from quadrivio_description.vehicle import VehicleParams


def clamp(x: float, lo: float, hi: float) -> float:
    return lo if x < lo else hi if x > hi else x


@dataclass(frozen=True)
class PidGains:
    kp: float = param(lo=0.0, hi=1e4, doc="proportional gain [output per unit error]")
    ki: float = param(0.0, lo=0.0, hi=1e4, doc="integral gain [output per unit error and second]")
    kd: float = param(0.0, lo=0.0, hi=1e4, doc="derivative gain [output per unit error rate]")
    i_limit: float = param(1.0, lo=0.0, hi=1e6, doc="bound on the integral term's contribution [output units]")


class Pid:
    """Parallel PID, derivative on the measurement (no kick on setpoint steps), clamped integrator.

    ``u = kp e + I + kd d(-y)/dt`` with ``I += ki e dt`` kept within ``+-i_limit``; the
    integrator is frozen while the output saturates in the direction of the error
    (conditional integration, no wind-up).
    """

    def __init__(self, gains: PidGains, out_lo: float, out_hi: float) -> None:
        self.g = gains
        self.lo, self.hi = out_lo, out_hi
        self.integral = 0.0
        self._prev_meas: Optional[float] = None

    def reset(self) -> None:
        self.integral = 0.0
        self._prev_meas = None

    def update(self, setpoint: float, measurement: float, dt: float) -> float:
        e = setpoint - measurement
        d = 0.0
        if self._prev_meas is not None and dt > 0.0:
            d = -(measurement - self._prev_meas) / dt
        self._prev_meas = measurement
        unsat = self.g.kp * e + self.integral + self.g.kd * d
        out = clamp(unsat, self.lo, self.hi)
        saturated_same_way = (unsat > self.hi and e > 0.0) or (unsat < self.lo and e < 0.0)
        if not saturated_same_way:
            self.integral = clamp(self.integral + self.g.ki * e * dt, -self.g.i_limit, self.g.i_limit)
        return out


@dataclass(frozen=True)
class HandlebarLoopParams:
    pid: PidGains = param(doc="PID from angle error [rad] to rate command [rad/s]")
    servo_tau: float = param(0.05, lo=0.0, hi=5.0, unit="s", doc="servo velocity time constant (0: ideal)")
    dead_time: float = param(0.0, lo=0.0, hi=2.0, unit="s", doc="command path dead time")
    max_rate: float = param(0.0, lo=0.0, hi=20.0, unit="rad/s",
                            doc="rate limit; 0 takes steering.max_rate from the vehicle")
    max_angle: float = param(0.0, lo=0.0, hi=1.5, unit="rad",
                             doc="angle limit; 0 takes steering.max_angle from the vehicle")


@dataclass(frozen=True)
class SpeedLoopParams:
    pid: PidGains = param(doc="PID from speed error [m/s] to throttle (+) / brake (-) demand in [-1, 1]")
    max_accel: float = param(0.0, lo=0.0, hi=50.0, unit="m/s^2", doc="setpoint ramp when speeding up (0: none)")
    max_decel: float = param(0.0, lo=0.0, hi=50.0, unit="m/s^2", doc="setpoint ramp when slowing down (0: none)")
    ramp_band: float = param(0.0, lo=0.0, hi=50.0, unit="m/s",
                             doc="the ramp stays within this of the measured speed (0: no band)")
    feedforward_offset: float = param(0.0, lo=0.0, hi=1.0, doc="throttle to keep rolling at any speed (f_0)")
    feedforward_gain: float = param(0.0, lo=0.0, hi=1.0, unit="s/m", doc="extra throttle per m/s of setpoint (f_1)")
    feedforward_accel: float = param(0.0, lo=0.0, hi=10.0, unit="s^2/m",
                                     doc="throttle per m/s^2 of setpoint ramp (f_a = m r / T_max)")
    throttle_tau: float = param(0.15, lo=0.0, hi=5.0, unit="s", doc="throttle servo time constant")
    brake_tau: float = param(0.10, lo=0.0, hi=5.0, unit="s", doc="brake servo time constant")
    brake_gain: float = param(1.0, lo=0.0, hi=10.0, doc="brake per unit of negative PID demand")
    brake_deadband: float = param(0.05, lo=0.0, hi=1.0, doc="negative demand below which the loop only closes the throttle")
    engine_brake: float = param(6.0, lo=0.0, hi=1e4, unit="N m s/rad",
                                doc="engine braking torque per wheel rad/s at closed throttle (total)")
    dead_time: float = param(0.0, lo=0.0, hi=2.0, unit="s", doc="command path dead time")
    overspeed_margin: float = param(1.0, lo=0.05, hi=10.0, unit="m/s",
                                    doc="runaway guard: speed beyond the command allowed before braking")
    rollback_margin: float = param(0.2, lo=0.01, hi=10.0, unit="m/s",
                                   doc="runaway guard: speed against the command allowed before braking")
    overspeed_brake_gain: float = param(2.0, lo=0.0, hi=100.0, unit="s/m",
                                        doc="runaway guard: brake per m/s beyond the overspeed margin (0: no guard)")


@dataclass(frozen=True)
class StepReference:
    """What a step response of the real vehicle looks like, for validation (Fig. 4)."""
    step: float = param(lo=-100.0, hi=100.0, doc="step amplitude [rad or m/s] from rest")
    rise_time: float = param(lo=0.0, hi=60.0, unit="s", doc="10-90 % rise time")
    rise_time_tol: float = param(0.2, lo=0.0, hi=1.0, doc="relative tolerance on the rise time")
    max_overshoot: float = param(0.10, lo=0.0, hi=2.0, doc="overshoot as a fraction of the step")


@dataclass(frozen=True)
class ActuatorParams:
    """Contents of ``config/actuators.yaml`` (what ``calibrate`` writes)."""
    handlebar: HandlebarLoopParams = param()
    speed: SpeedLoopParams = param()
    handlebar_reference: Optional[StepReference] = param(None, doc="expected handlebar step response")
    speed_reference: Optional[StepReference] = param(None, doc="expected speed step response")


class _DelayLine:
    """Pure transport delay of ``n`` samples (dead time = n x cycle)."""

    def __init__(self, n: int, initial: float = 0.0) -> None:
        self.buf: Deque[float] = deque([initial] * n, maxlen=n) if n > 0 else deque()
        self.n = n

    def push(self, x: float) -> float:
        if self.n == 0:
            return x
        out = self.buf[0]
        self.buf.append(x)
        return out


def first_order(y: float, target: float, tau: float, dt: float) -> float:
    """Exact step of ``y' = (target - y) / tau`` over ``dt`` (``tau = 0``: jump to target)."""
    if tau <= 0.0:
        return target
    return target + (y - target) * math.exp(-dt / tau)


class HandlebarLoop:
    """Handlebar position servo under PID control (see module docstring)."""

    def __init__(self, p: HandlebarLoopParams, vehicle: VehicleParams, dt: float) -> None:
        self.p = p
        self.dt = dt
        self.max_angle = p.max_angle or vehicle.steering.max_angle
        self.max_rate = p.max_rate or vehicle.steering.max_rate
        self.pid = Pid(p.pid, -self.max_rate, self.max_rate)
        self.delay = _DelayLine(int(round(p.dead_time / dt)))
        self.angle = 0.0  # [rad]
        self.rate = 0.0  # [rad/s]

    def reset(self, angle: float = 0.0) -> None:
        self.angle, self.rate = angle, 0.0
        self.pid.reset()
        self.delay = _DelayLine(self.delay.n, angle)

    def step(self, setpoint: float) -> float:
        sp = clamp(self.delay.push(setpoint), -self.max_angle, self.max_angle)
        u = self.pid.update(sp, self.angle, self.dt)
        self.rate = first_order(self.rate, u, self.p.servo_tau, self.dt)
        self.angle += self.rate * self.dt
        if abs(self.angle) > self.max_angle:  # mechanical stop
            self.angle = math.copysign(self.max_angle, self.angle)
            self.rate = 0.0
        return self.angle


class SpeedLoop:
    """Speed PID commanding throttle and brake servos; returns wheel torques (see module docstring)."""

    def __init__(self, p: SpeedLoopParams, vehicle: VehicleParams, dt: float) -> None:
        self.p = p
        self.v = vehicle
        self.dt = dt
        self.pid = Pid(p.pid, -1.0, 1.0)
        self.delay = _DelayLine(int(round(p.dead_time / dt)))
        self.throttle = 0.0  # [1]
        self.brake = 0.0  # [1]
        self.gear = 1  # +1 forward, -1 reverse (engaged by the sign of the setpoint)
        self.ramp = 0.0  # [m/s] ramped setpoint
        self.ramp_free = 0.0  # [m/s] the same ramp without the band (runaway guard)
        self.overspeed = 0.0  # [m/s] how far outside the allowed speeds the vehicle was last cycle

    def reset(self) -> None:
        self.pid.reset()
        self.delay = _DelayLine(self.delay.n)
        self.throttle = self.brake = 0.0
        self.gear = 1
        self.ramp = self.ramp_free = self.overspeed = 0.0

    def _ramp_step(self, ramp: float, sp: float) -> float:
        """The change of a ramp at ``ramp`` toward ``sp`` in one cycle, within the acceleration limits."""
        d = sp - ramp
        speeding_up = abs(sp) > abs(ramp) and sp * ramp >= 0.0
        limit = self.p.max_accel if speeding_up else self.p.max_decel
        return clamp(d, -limit * self.dt, limit * self.dt) if limit > 0.0 else d

    def _free_ramp(self, sp: float) -> float:
        self.ramp_free += self._ramp_step(self.ramp_free, sp)
        return self.ramp_free

    def _runaway(self, target: float, speed: float) -> Tuple[float, bool]:
        """How far [m/s] the speed along the commanded direction is outside
        ``[-m_r, max(|cmd|, |r_free|) + m_o]``. The direction is the command's, not the
        engaged gear's: the banded ramp follows a vehicle rolling back through zero and
        would engage reverse with it. Also says whether the vehicle moves against the command."""
        direction = 1 if target > 1e-3 else -1 if target < -1e-3 else self.gear
        along = direction * speed
        limit = max(abs(target), abs(self._free_ramp(target))) + self.p.overspeed_margin
        if along < -self.p.rollback_margin:
            return -self.p.rollback_margin - along, True
        return max(0.0, along - limit), False

    def _ramp(self, sp: float, speed: float) -> Tuple[float, float]:
        """Move the ramped setpoint toward ``sp`` at most at the acceleration limits and
        within ``ramp_band`` of the measured speed (the ramp waits for a vehicle that cannot
        follow it, e.g. while the parking brake releases); returns it and its rate [m/s^2]."""
        if self.p.ramp_band > 0.0:
            self.ramp = clamp(self.ramp, speed - self.p.ramp_band, speed + self.p.ramp_band)
        d = self._ramp_step(self.ramp, sp)
        self.ramp += d
        return self.ramp, d / self.dt

    def step(self, speed_sp: float, brake_sp: float, speed: float, wheel_rate: float) -> Tuple[float, float]:
        """One PLC cycle. ``speed`` [m/s] and ``wheel_rate`` [rad/s] are the measured rear wheel
        speed and angular rate. Returns ``(drive_torque, brake_torque)`` [N m], totals over the
        driven wheels and over all wheels respectively; the brake torque opposes rotation."""
        target = self.delay.push(speed_sp)
        sp, rate = self._ramp(target, speed)
        if sp > 1e-3:
            self.gear = 1
        elif sp < -1e-3:
            self.gear = -1
        # The loop works on the speed in the direction of travel of the engaged gear.
        ff = self.p.feedforward_offset + self.p.feedforward_gain * abs(sp) if abs(sp) > 1e-3 else 0.0
        if self.p.max_accel > 0.0 or self.p.max_decel > 0.0:  # a ramp: its acceleration is known
            ff += self.p.feedforward_accel * self.gear * rate
        self.pid.lo, self.pid.hi = -1.0 - ff, 1.0 - ff  # saturation (and anti-windup) on the total
        u = ff + self.pid.update(self.gear * sp, self.gear * speed, self.dt)
        throttle_cmd = max(u, 0.0) * (1.0 - clamp(brake_sp, 0.0, 1.0))  # a brake demand closes the throttle
        brake_cmd = max(brake_sp, self.p.brake_gain * max(-u - self.p.brake_deadband, 0.0))
        if abs(target) <= 1e-3 and abs(sp) <= 1e-3 and abs(speed) < 0.05:  # standing still: hold the brake
            throttle_cmd, brake_cmd = 0.0, max(brake_cmd, 0.3)
        self.overspeed, against = self._runaway(target, speed)
        if self.overspeed > 0.0 and self.p.overspeed_brake_gain > 0.0:
            # Against the command: full brake (the vehicle is rolling back). Too fast: in proportion.
            throttle_cmd = 0.0
            brake_cmd = 1.0 if against else max(brake_cmd, self.p.overspeed_brake_gain * self.overspeed)
        self.throttle = first_order(self.throttle, clamp(throttle_cmd, 0.0, 1.0), self.p.throttle_tau, self.dt)
        self.brake = first_order(self.brake, clamp(brake_cmd, 0.0, 1.0), self.p.brake_tau, self.dt)
        drive = self.gear * self.throttle * self.v.drivetrain.max_drive_torque
        drive -= self.p.engine_brake * (1.0 - self.throttle) * wheel_rate
        return drive, self.brake * self.v.drivetrain.max_brake_torque


@dataclass
class Actuation:
    """What the low-level loops command for one PLC cycle."""
    handlebar: float = 0.0  # [rad] handlebar angle reached by the servo
    drive_torque: float = 0.0  # [N m] total at the driven wheels (engine braking included)
    brake_torque: float = 0.0  # [N m] total over all wheels, opposing rotation
    throttle: float = 0.0  # [1]
    brake: float = 0.0  # [1]


class LowLevelControl:
    """Both loops together, with setpoint limits from the vehicle parameters.

    ``clamp`` bounds a setpoint to the vehicle's limits (speed in
    ``[-max_reverse_speed, max_speed]``, handlebar within ``+-max_angle``, brake in
    ``[0, 1]``) and says whether it had to.
    """

    def __init__(self, params: ActuatorParams, vehicle: VehicleParams, cycle: float) -> None:
        self.params = params
        self.vehicle = vehicle
        self.cycle = cycle
        self.handlebar = HandlebarLoop(params.handlebar, vehicle, cycle)
        self.speed = SpeedLoop(params.speed, vehicle, cycle)
        self.out = Actuation()
        self.speed_measured = 0.0  # [m/s] wheel speed the loops last acted on

    def reset(self) -> None:
        self.handlebar.reset()
        self.speed.reset()
        self.out = Actuation()

    def clamp(self, speed: float, handlebar: float, brake: float) -> Tuple[float, float, float, bool]:
        d = self.vehicle.drivetrain
        c_speed = clamp(speed, -d.max_reverse_speed, d.max_speed)
        c_handlebar = clamp(handlebar, -self.handlebar.max_angle, self.handlebar.max_angle)
        c_brake = clamp(brake, 0.0, 1.0)
        return c_speed, c_handlebar, c_brake, (c_speed, c_handlebar, c_brake) != (speed, handlebar, brake)

    def step(self, speed_sp: float, handlebar_sp: Optional[float], brake_sp: float,
             wheel_speed: float, wheel_rate: float) -> Actuation:
        """One cycle. ``handlebar_sp = None`` disables the handlebar servo (it holds its angle)."""
        h = self.handlebar.angle if handlebar_sp is None else self.handlebar.step(handlebar_sp)
        self.speed_measured = wheel_speed
        drive, brake_torque = self.speed.step(speed_sp, brake_sp, wheel_speed, wheel_rate)
        self.out = Actuation(h, drive, brake_torque, self.speed.throttle, self.speed.brake)
        return self.out


def load_actuators(path: str) -> ActuatorParams:
    from quadrivio_config import load_dataclass

    return load_dataclass(ActuatorParams, path)
