"""Vehicle parameters of the Quadrivio ATV: the single source of truth.

Every package reads dimensions, masses and limits from ``config/vehicle.yaml`` through
:class:`VehicleParams`; the URDF is generated from it (:mod:`quadrivio_description.urdf`).
Quantities that follow from others (track, wheel radius, chassis mass, corner loads,
steering limits of each wheel) are derived here and nowhere else.

Frames (REP-105): ``base_link`` is the centre of the rear axle, x forward, y left,
z up. Heights in this file are above flat ground with the vehicle at rest.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import Any, Dict, Mapping, Optional, Tuple

from quadrivio_config import ConfigError, from_mapping, load_yaml, param, replace_nested
from .paths import package_dir as _package_dir

GRAVITY = 9.81  # [m/s^2]


@dataclass(frozen=True)
class BodyParams:
    length: float = param(lo=0.5, hi=10.0, unit="m", doc="overall length (Table 1)")
    width: float = param(lo=0.3, hi=5.0, unit="m", doc="overall width, tyre outer faces included (Table 1)")
    height: float = param(lo=0.3, hi=5.0, unit="m", doc="overall height (Table 1)")
    mass: float = param(lo=1.0, hi=10000.0, unit="kg", doc="total mass, wheels and equipment included (Table 2)")
    rear_overhang: float = param(lo=0.0, hi=5.0, unit="m", doc="rear bumper behind the rear axle")
    com_x: float = param(lo=0.0, hi=10.0, unit="m", doc="centre of mass ahead of the rear axle")
    com_height: float = param(lo=0.05, hi=5.0, unit="m", doc="centre of mass above the ground")
    ground_clearance: float = param(lo=0.0, hi=2.0, unit="m", doc="lowest point of the body above the ground")
    body_width: float = param(lo=0.1, hi=5.0, unit="m", doc="width of the body box (between the fenders)")
    body_top: float = param(lo=0.1, hi=5.0, unit="m", doc="top of the body box (seat, racks) above the ground")


@dataclass(frozen=True)
class WheelParams:
    diameter: float = param(lo=0.1, hi=3.0, unit="m", doc="tyre outer diameter (Table 2: 635 mm)")
    front_width: float = param(lo=0.02, hi=1.0, unit="m", doc="front tyre width (Table 2: 201 mm)")
    rear_width: float = param(lo=0.02, hi=1.0, unit="m", doc="rear tyre width (Table 2: 247 mm)")
    mass: float = param(lo=0.1, hi=200.0, unit="kg", doc="mass of one wheel with tyre")
    hub_mass: float = param(lo=0.1, hi=100.0, unit="kg", doc="unsprung mass of one hub/knuckle")
    lateral_friction: float = param(lo=0.0, hi=3.0, unit="1", doc="tyre-ground Coulomb friction coefficient")
    rolling_friction: float = param(lo=0.0, hi=1.0, unit="m", doc="rolling resistance lever arm (Bullet rollingFriction)")
    spinning_friction: float = param(lo=0.0, hi=1.0, unit="m", doc="torsional friction at the contact patch")
    contact_stiffness: float = param(lo=1e3, hi=1e9, unit="N/m", doc="tyre vertical stiffness")
    contact_damping: float = param(lo=0.0, hi=1e7, unit="N s/m", doc="tyre vertical damping")


@dataclass(frozen=True)
class AxleSuspension:
    stiffness: float = param(lo=100.0, hi=1e7, unit="N/m", doc="spring rate at the wheel")
    damping: float = param(lo=0.0, hi=1e6, unit="N s/m", doc="damper rate at the wheel")
    travel_up: float = param(lo=0.0, hi=1.0, unit="m", doc="compression travel from the static position to the bump stop")
    travel_down: float = param(lo=0.0, hi=1.0, unit="m", doc="extension travel from the static position to full droop")


@dataclass(frozen=True)
class SuspensionParams:
    front: AxleSuspension = param(doc="independent double wishbone, front")
    rear: AxleSuspension = param(doc="independent double wishbone, rear")


@dataclass(frozen=True)
class SteeringParams:
    max_angle: float = param(lo=0.01, hi=1.2, unit="rad", doc="handlebar angle limit, each side")
    max_rate: float = param(lo=0.01, hi=20.0, unit="rad/s", doc="handlebar servo rate limit")
    ratio: float = param(lo=0.1, hi=10.0, unit="1", doc="virtual (bicycle) front wheel angle per handlebar angle")


@dataclass(frozen=True)
class DrivetrainParams:
    drive: str = param(choices=("2wd", "4wd", "4wd_locked"),
                       doc="Table 1's drive train: solid rear axle only; plus the front wheels through an open "
                           "differential; all four locked together")
    max_drive_torque: float = param(lo=0.0, hi=1e5, unit="N m", doc="total wheel torque at full throttle")
    max_brake_torque: float = param(lo=0.0, hi=1e5, unit="N m", doc="total brake torque at full brake, all wheels")
    max_speed: float = param(lo=0.1, hi=50.0, unit="m/s", doc="forward speed setpoint limit")
    max_reverse_speed: float = param(lo=0.0, hi=20.0, unit="m/s", doc="reverse speed setpoint limit")
    axle_torque_limit: float = param(5000.0, lo=1.0, hi=1e6, unit="N m",
                                     doc="largest torque a locked shaft transmits between its wheels")


@dataclass(frozen=True)
class SensorMount:
    xyz: Tuple[float, float, float] = param(unit="m", doc="position in base_link")
    rpy: Tuple[float, float, float] = param((0.0, 0.0, 0.0), unit="rad", doc="roll, pitch, yaw in base_link")


REQUIRED_SENSOR_FRAMES = ("gps_link", "imu_link", "mag_link", "laser_front", "laser_rear",
                          "camera_left", "camera_right")


@dataclass(frozen=True)
class VehicleParams:
    """All vehicle parameters (``config/vehicle.yaml``) and the quantities derived from them."""

    body: BodyParams = param()
    wheelbase: float = param(lo=0.2, hi=10.0, unit="m", doc="front to rear axle (Table 2: 1250 mm)")
    wheels: WheelParams = param()
    suspension: SuspensionParams = param()
    steering: SteeringParams = param()
    drivetrain: DrivetrainParams = param()
    sensors: Dict[str, SensorMount] = param(doc="sensor frames, child links of base_link")
    name: str = param("quadrivio", doc="robot name in the URDF")

    def __post_init__(self) -> None:
        missing = [f for f in REQUIRED_SENSOR_FRAMES if f not in self.sensors]
        if missing:
            raise ValueError(f"'sensors' lacks the frame(s) {', '.join(missing)}")
        if self.front_track <= 0.0 or self.rear_track <= 0.0:
            raise ValueError(f"'body.width' = {self.body.width} leaves no track for tyres of "
                             f"{self.wheels.front_width} / {self.wheels.rear_width} m")
        if not 0.0 < self.body.com_x < self.wheelbase:
            raise ValueError(f"'body.com_x' = {self.body.com_x} must lie between the axles (0, {self.wheelbase}) m")
        if self.chassis_mass <= 0.0:
            raise ValueError(f"'body.mass' = {self.body.mass} kg is less than the wheels and hubs "
                             f"({4 * (self.wheels.mass + self.wheels.hub_mass)} kg)")
        if self.body.ground_clearance >= self.body.body_top:
            raise ValueError("'body.ground_clearance' must be below 'body.body_top'")
        front_overhang = self.body.length - self.body.rear_overhang - self.wheelbase
        if min(front_overhang, self.body.rear_overhang) < self.wheel_radius:
            raise ValueError(f"'body.length' = {self.body.length}, 'body.rear_overhang' = {self.body.rear_overhang} "
                             f"and 'wheelbase' = {self.wheelbase} leave less than a wheel radius "
                             f"({self.wheel_radius} m) ahead of the front or behind the rear axle")

    # ------------------------------------------------------------------ derived
    @property
    def wheel_radius(self) -> float:
        """Unloaded rolling radius r = D / 2 [m]."""
        return 0.5 * self.wheels.diameter

    @property
    def front_track(self) -> float:
        """Front track [m] = overall width - front tyre width.

        Table 2's 1920 mm cannot fit a 1.18 m wide vehicle; the outer faces of the
        tyres are taken as the overall width, so the track (centre to centre of the
        contact patches) is the width minus one tyre width.
        """
        return self.body.width - self.wheels.front_width

    @property
    def rear_track(self) -> float:
        """Rear track [m] = overall width - rear tyre width (see :attr:`front_track`)."""
        return self.body.width - self.wheels.rear_width

    @property
    def mean_track(self) -> float:
        return 0.5 * (self.front_track + self.rear_track)

    @property
    def chassis_mass(self) -> float:
        """Sprung mass [kg]: total minus four wheels and four hubs."""
        return self.body.mass - 4.0 * (self.wheels.mass + self.wheels.hub_mass)

    @property
    def static_stability_factor(self) -> float:
        """SSF = T / (2 h): lateral acceleration in g at which a rigid vehicle tips over."""
        return self.mean_track / (2.0 * self.body.com_height)

    @property
    def max_wheel_angle(self) -> float:
        """Virtual (bicycle-model) front wheel angle at full handlebar [rad]."""
        return self.steering.ratio * self.steering.max_angle

    @property
    def min_turning_radius(self) -> float:
        """Turning radius of the rear axle centre at full lock, R = L / tan(delta_max) [m]."""
        return self.wheelbase / math.tan(self.max_wheel_angle)

    def corner_static_load(self, front: bool) -> float:
        """Static sprung weight carried by one spring [N] (chassis only, lever rule)."""
        share = self.body.com_x / self.wheelbase if front else 1.0 - self.body.com_x / self.wheelbase
        return 0.5 * share * self.chassis_mass * GRAVITY

    def wheel_centres(self) -> Dict[str, Tuple[float, float, float]]:
        """Wheel centres in base_link at the static ride height [m]."""
        L, tf, tr = self.wheelbase, self.front_track, self.rear_track
        return {
            "front_left": (L, 0.5 * tf, 0.0),
            "front_right": (L, -0.5 * tf, 0.0),
            "rear_left": (0.0, 0.5 * tr, 0.0),
            "rear_right": (0.0, -0.5 * tr, 0.0),
        }


def package_dir() -> str:
    """The quadrivio_description package directory (works in the source tree and devel space)."""
    return _package_dir("quadrivio_description", __file__, 2)


def default_vehicle_file() -> str:
    return os.path.join(package_dir(), "config", "vehicle.yaml")


def load_vehicle(path: str = "") -> VehicleParams:
    """Load and validate the vehicle parameters (default: the package's ``config/vehicle.yaml``)."""
    path = path or default_vehicle_file()
    return from_mapping(VehicleParams, load_yaml(path), path)


def with_overrides(vehicle: VehicleParams, overrides: Any, source: str) -> VehicleParams:
    """``vehicle`` with a scenario's ``vehicle:`` section applied (drive train, masses,
    limits: any keys of vehicle.yaml, nested), validated as a full load is; none: unchanged."""
    if overrides is None or overrides == {}:
        return vehicle
    if not isinstance(overrides, Mapping):
        raise ConfigError(f"{source}: must be a mapping of vehicle.yaml keys (e.g. drivetrain: {{drive: 4wd}}), "
                          f"got {overrides!r}")
    return replace_nested(vehicle, overrides, source)


def scenario_vehicle(path: str, vehicle: Optional[VehicleParams] = None) -> VehicleParams:
    """The vehicle of the scenario file ``path``: ``vehicle`` (default: vehicle.yaml's)
    with the scenario's ``vehicle:`` section applied."""
    data = load_yaml(path) or {}
    base = vehicle if vehicle is not None else load_vehicle()
    return with_overrides(base, data.get("vehicle") if isinstance(data, Mapping) else None, f"{path}: vehicle")


def vehicle_from_mapping(data, source: str = "/vehicle") -> VehicleParams:
    """Validate vehicle parameters already loaded elsewhere (e.g. the ``/vehicle`` ROS namespace)."""
    return from_mapping(VehicleParams, data, source)


__all__ = ["VehicleParams", "load_vehicle", "vehicle_from_mapping", "with_overrides", "scenario_vehicle", "default_vehicle_file", "ConfigError",
           "GRAVITY", "REQUIRED_SENSOR_FRAMES"]
