"""Low-level loops: PID properties, handlebar servo limits and dead time, speed loop and
engine braking, setpoint clamping."""
import math

import numpy as np
import pytest

from quadrivio_description.vehicle import load_vehicle
from quadrivio_sim.actuators import (ActuatorParams, HandlebarLoop, HandlebarLoopParams, LowLevelControl, Pid,
                                     PidGains, SpeedLoop, SpeedLoopParams, first_order, load_actuators)
from quadrivio_sim.paths import package_file

DT = 0.01


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


def test_pid_proportional_and_saturation():
    pid = Pid(PidGains(kp=2.0), -1.0, 1.0)
    assert pid.update(0.3, 0.0, DT) == pytest.approx(0.6)
    assert pid.update(5.0, 0.0, DT) == 1.0
    assert pid.update(-5.0, 0.0, DT) == -1.0


def test_pid_no_derivative_kick_on_setpoint_step():
    pid = Pid(PidGains(kp=0.0, kd=1.0), -10, 10)
    pid.update(0.0, 0.0, DT)
    assert pid.update(1.0, 0.0, DT) == 0.0  # setpoint jumped, measurement did not
    assert pid.update(1.0, 0.1, DT) == pytest.approx(-10.0)  # -kd dy/dt, clamped


def test_pid_anti_windup():
    pid = Pid(PidGains(kp=1.0, ki=5.0, i_limit=10.0), -1.0, 1.0)
    for _ in range(1000):  # saturated for 10 s with a large error
        pid.update(10.0, 0.0, DT)
    assert pid.integral < 0.1  # frozen while saturated in the error's direction
    assert pid.update(-0.5, 0.0, DT) < 0.0  # reacts at once when the error reverses


def test_first_order_exact():
    assert first_order(0.0, 1.0, 0.5, 0.5) == pytest.approx(1 - math.exp(-1))
    assert first_order(0.3, 1.0, 0.0, 0.01) == 1.0


def _handlebar(vehicle, **kw):
    p = HandlebarLoopParams(pid=PidGains(kp=4.0, ki=0.0, i_limit=0.2), **kw)
    return HandlebarLoop(p, vehicle, DT)


def test_handlebar_rate_and_angle_limits(vehicle):
    loop = _handlebar(vehicle, servo_tau=0.05)
    angles = [loop.step(0.3) for _ in range(300)]
    rates = np.diff([0.0] + angles) / DT
    assert rates.max() <= vehicle.steering.max_rate + 1e-9
    assert angles[-1] == pytest.approx(0.3, abs=2e-3)
    loop.reset()
    angles = [loop.step(5.0) for _ in range(300)]  # beyond the stop
    assert max(angles) <= vehicle.steering.max_angle + 1e-12
    assert angles[-1] == pytest.approx(vehicle.steering.max_angle, abs=1e-6)


def test_handlebar_dead_time(vehicle):
    loop = _handlebar(vehicle, dead_time=0.1, servo_tau=0.0)
    angles = [loop.step(0.2) for _ in range(30)]
    assert all(a == 0.0 for a in angles[:10])  # nothing moves during the 0.1 s dead time
    assert angles[11] > 0.0


class PointMass:
    """Vehicle as a point mass on its rear wheels: m v' = (T_drive - T_brake sign(v)) / r."""

    def __init__(self, vehicle):
        self.m, self.r, self.v = vehicle.body.mass, vehicle.wheel_radius, 0.0

    def step(self, drive, brake):
        f = drive / self.r
        fb = brake / self.r
        if self.v == 0.0 and abs(f) <= fb:
            return 0.0
        f -= math.copysign(fb, self.v if self.v != 0 else f)
        v_new = self.v + f / self.m * DT
        self.v = 0.0 if self.v != 0 and v_new * self.v < 0 else v_new
        return self.v


def _speed_loop(vehicle, **kw):
    p = SpeedLoopParams(pid=PidGains(kp=0.25, ki=0.08, i_limit=0.4), **kw)
    return SpeedLoop(p, vehicle, DT)


def test_speed_loop_reaches_setpoint_without_large_overshoot(vehicle):
    loop, plant = _speed_loop(vehicle), PointMass(vehicle)
    vs = []
    for _ in range(1500):
        drive, brake = loop.step(3.0, 0.0, plant.v, plant.v / plant.r)
        vs.append(plant.step(drive, brake))
    assert vs[-1] == pytest.approx(3.0, abs=0.03)
    assert max(vs) < 3.3


def test_speed_loop_engine_braking_when_throttle_drops(vehicle):
    loop, plant = _speed_loop(vehicle, engine_brake=6.0, brake_deadband=0.5), PointMass(vehicle)
    for _ in range(1500):
        drive, brake = loop.step(3.0, 0.0, plant.v, plant.v / plant.r)
        plant.step(drive, brake)
    v_cruise = plant.v
    drive, brake = 0.0, 0.0
    for _ in range(50):  # setpoint drops a little: within the deadband, no brake
        drive, brake = loop.step(2.5, 0.0, plant.v, plant.v / plant.r)
        plant.step(drive, brake)
    assert brake == pytest.approx(0.0, abs=1e-9)
    assert loop.throttle < 0.2
    assert drive < 0.0  # engine braking torque opposes the rotation
    assert plant.v < v_cruise


def test_speed_loop_reverse_and_hold(vehicle):
    loop, plant = _speed_loop(vehicle), PointMass(vehicle)
    for _ in range(1000):
        drive, brake = loop.step(-1.0, 0.0, plant.v, plant.v / plant.r)
        plant.step(drive, brake)
    assert loop.gear == -1
    assert plant.v == pytest.approx(-1.0, abs=0.05)
    for _ in range(800):
        drive, brake = loop.step(0.0, 0.0, plant.v, plant.v / plant.r)
        plant.step(drive, brake)
    assert abs(plant.v) < 0.05
    assert loop.brake > 0.2  # holding the brake at standstill


def test_clamp_reports(vehicle):
    ctl = LowLevelControl(load_actuators(package_file("config", "actuators.yaml")), vehicle, DT)
    assert ctl.clamp(1.0, 0.1, 0.0) == (1.0, 0.1, 0.0, False)
    s, h, b, clamped = ctl.clamp(100.0, -2.0, 3.0)
    assert clamped
    assert (s, h, b) == (vehicle.drivetrain.max_speed, -vehicle.steering.max_angle, 1.0)
    assert ctl.clamp(-10.0, 0.0, -1.0)[0] == -vehicle.drivetrain.max_reverse_speed


def test_default_actuator_file_is_valid():
    params = load_actuators(package_file("config", "actuators.yaml"))
    assert isinstance(params, ActuatorParams)
    assert params.handlebar_reference is not None and params.speed_reference is not None
