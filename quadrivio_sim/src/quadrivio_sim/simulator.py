"""The simulator core: world, emulated PLC program and sensor schedule on one sim clock.

Time is ``t = k * dt`` for step count ``k`` (no accumulated float error, identical
stamps run to run). Each :meth:`Simulator.step`:

1. every PLC cycle: a setpoint script, when set, feeds the PLC as the autonomous
   source (open-loop runs, replays); the PLC program runs its watchdog and low-level loops on the
   measured rear wheel speed, and the world receives handlebar angle and torques;
2. the physics advances by ``dt``;
3. every output whose period divides the new step count is sampled: ground truth,
   joint states, PLC state, GPS, IMU, magnetometer, lasers, cameras.

Every rate must be a whole number of physics steps; the check happens at start-up
and names the offending key. ROS-free: the simulator node turns the returned samples
into messages.
"""

from __future__ import annotations

import math
import zlib
from collections import deque
from dataclasses import dataclass
from typing import Callable, Deque, Dict, List, Optional, Tuple

import numpy as np

from quadrivio_config import ConfigError, param
from quadrivio_description.site import SiteParams, load_site
from quadrivio_description.vehicle import VehicleParams
from quadrivio_plc import protocol

from .actors import ActorMotion, ActorParams
from .actuators import ActuatorParams, LowLevelControl
from .noise import Latency
from .plc_emulator import PlcLogic, PlcParams
from .script import SetpointScript
from .sensors import (CameraSensor, GpsSensor, ImuSensor, LaserSensor, MagSensor, SensorsParams)
from quadrivio_terrain.terrain import TerrainParams
from quadrivio_navigation.maps import MapParams, load_map, obstacles_from_grid
from .world import Obstacle, PhysicsParams, Pose2D, World, quat_to_rows, rotate_inverse
from quadrivio_description.vehicle import GRAVITY


@dataclass(frozen=True)
class MeasurementParams:
    """What the PLC's encoders get wrong (the calibration the localization must find out).
    The defaults are a perfect vehicle."""
    handlebar_offset: float = param(0.0, lo=-0.5, hi=0.5, unit="rad",
                                    doc="the steered wheels stand this much left of the handlebar angle the PLC "
                                        "measures and reports (a misaligned encoder)")
    wheel_speed_scale: float = param(1.0, lo=0.5, hi=2.0,
                                     doc="measured over true rear wheel speed (a wrong wheel radius); the PLC's "
                                         "speed loop acts on the measured speed, as on the vehicle")
    wheel_speed_dead: Tuple[Tuple[float, float], ...] = param(
        (), unit="s", doc="[[start, end], ...] sim time during which the reported wheel speed reads 0 (a dead "
                          "channel; the PLC's own speed loop keeps its encoder, so the vehicle drives on)")


@dataclass(frozen=True)
class SimParams:
    """Contents of ``config/sim.yaml`` (the simulator node's private parameters)."""
    physics: PhysicsParams = param(PhysicsParams())
    terrain: TerrainParams = param(TerrainParams())
    spawn: Pose2D = param(Pose2D(), doc="initial pose of base_link in the map frame")
    obstacles: Tuple[Obstacle, ...] = param((), doc="static boxes and cylinders (trees, buildings)")
    actors: Tuple[ActorParams, ...] = param((), doc="people, animals, vehicles: standing or moving (actors.py)")
    actors_rate: float = param(10.0, lo=1.0, hi=1000.0, unit="Hz", doc="/ground_truth/actors rate")
    map: MapParams = param(MapParams(), doc="a map_server map whose occupied cells become static obstacles")
    seed: int = param(0, lo=0, hi=2 ** 63 - 1, doc="seed of every random draw in the simulator (terrain)")
    ground_truth_rate: float = param(50.0, lo=1.0, hi=1000.0, unit="Hz", doc="/ground_truth/odom rate")
    joint_states_rate: float = param(20.0, lo=1.0, hi=1000.0, unit="Hz", doc="/joint_states rate")
    sensors: SensorsParams = param(SensorsParams())
    plc: PlcParams = param(PlcParams())
    measurement: MeasurementParams = param(MeasurementParams(), doc="encoder errors and faults (default: none)")


@dataclass(frozen=True)
class GroundTruth:
    stamp: float
    position: Tuple[float, float, float]  # base_link origin in map [m]
    orientation: Tuple[float, float, float, float]  # x, y, z, w
    linear_velocity: Tuple[float, float, float]  # [m/s] in map
    angular_velocity: Tuple[float, float, float]  # [rad/s] in map


@dataclass(frozen=True)
class ActorSample:
    name: str
    kind: str  # person | animal | vehicle | object | obstacle (a static scenario obstacle)
    shape: str  # cylinder | box
    x: float
    y: float
    yaw: float
    size: Tuple[float, float, float]  # length (a cylinder's diameter), width, height [m]
    speed: float  # [m/s]


@dataclass(frozen=True)
class ContactEvent:
    """The vehicle began to touch a body that is not the ground."""
    stamp: float
    body: str
    kind: str  # person | animal | vehicle | object | obstacle | map
    speed: float  # [m/s] the vehicle's horizontal speed at that step
    position: Tuple[float, float]  # base_link [m] in the map frame


@dataclass(frozen=True)
class JointSample:
    stamp: float
    names: Tuple[str, ...]
    positions: Tuple[float, ...]
    velocities: Tuple[float, ...]


def with_scenario_world(p: "SimParams", actors, map_section, source: str, where: str) -> "SimParams":
    """The simulator's parameters ``p`` with a scenario's world: its top-level ``actors``
    (the ``actors:`` section's list, or None) added, its ``map:`` section (a dict, or None)
    applied, and the map file and DEM image resolved against the scenario file ``source``.
    ``sim_node`` and the one-process loop both build their world this way. ConfigError
    naming ``where`` and the problem."""
    from dataclasses import replace

    from quadrivio_config import replace_nested
    from quadrivio_navigation.maps import resolve_map_file

    from .actors import load_actors

    if actors:
        p = replace(p, actors=p.actors + tuple(load_actors(actors, f"{where}: actors")))
    world_map = replace_nested(p.map, map_section, f"{where}: map") if map_section else p.map
    p = replace(p, map=replace(world_map, file=resolve_map_file(world_map.file, source)))
    if p.terrain.image:  # a DEM image or GeoTIFF: relative to the scenario's folder, as the map
        p = replace(p, terrain=replace(p.terrain, image=resolve_map_file(p.terrain.image, source)))
    return p


def steps_per_period(rate: float, dt: float, key: str) -> int:
    """Physics steps per sample period; the period must be a whole number of steps."""
    n = 1.0 / (rate * dt)
    k = int(round(n))
    if k < 1 or abs(n - k) > 1e-6 * max(1.0, n):
        raise ConfigError(f"'{key}' = {rate} Hz is not a whole number of physics steps of {dt} s "
                          f"(1 / (rate x dt) = {n:.4f}); pick a rate that divides {1.0 / dt:g} Hz")
    return k


class Simulator:
    def __init__(self, params: SimParams, vehicle: VehicleParams, actuators: ActuatorParams,
                 urdf_text: str, site: Optional[SiteParams] = None) -> None:
        self.params = params
        self.vehicle = vehicle
        self.dt = params.physics.dt
        self.rng = np.random.default_rng(params.seed)
        self.site = site or load_site()
        frame = self.site.local_frame()  # places georeferenced maps and DEMs
        blocks = []
        self.map_report: Tuple[str, ...] = ()  # the map's summary and warnings (the node logs them)
        if params.map.file:
            grid = load_map(params.map.file, frame)  # MapError names the file and the problem
            blocks = obstacles_from_grid(grid, params.map.occupied, params.map.tree_size)
            self.map_report = (grid.summary,) + tuple(grid.warnings)
        self.map_blocks = blocks
        self.world = World(vehicle, urdf_text, params.physics, params.terrain, self.rng, params.obstacles,
                           params.spawn, blocks, params.map.obstacle_height, params.actors, frame)
        self.actors = [ActorMotion(a) for a in params.actors]
        b = vehicle.body  # base_link to the body's farthest corner: where an actor may come near it
        self.vehicle_reach = math.hypot(max(b.length - b.rear_overhang, b.rear_overhang), 0.5 * b.width)
        self.touching: List[int] = []
        self.contacts: List[ContactEvent] = []  # every contact of the run, in order
        self.control = LowLevelControl(actuators, vehicle, params.plc.cycle)
        self.plc = PlcLogic(params.plc, self.control)
        s = params.sensors
        dt = self.dt
        self.cycle_steps = steps_per_period(1.0 / params.plc.cycle, dt, "plc.cycle")
        self.gps = GpsSensor(self.world)
        self.imu = ImuSensor(self.world, s.imu.rate)
        self.mag = MagSensor(self.world, self.site.magnetic_field)
        self.lasers = [LaserSensor(self.world, s.lasers, f) for f in s.lasers.frames]
        self.cameras = [CameraSensor(self.world, s.cameras, f) for f in s.cameras.frames] if s.cameras.enabled else []
        # (name, period in steps, sampler)
        self.outputs: List[Tuple[str, int, Callable[[float], object]]] = [
            ("ground_truth", steps_per_period(params.ground_truth_rate, dt, "ground_truth_rate"), self._ground_truth),
            ("joint_states", steps_per_period(params.joint_states_rate, dt, "joint_states_rate"), self._joints),
            ("plc_state", steps_per_period(params.plc.state_rate, dt, "plc.state_rate"), self._plc_state),
            ("gps", steps_per_period(s.gps.rate, dt, "sensors.gps.rate"), self.gps.sample),
            ("imu", steps_per_period(s.imu.rate, dt, "sensors.imu.rate"), self.imu.sample),
            ("mag", steps_per_period(s.mag.rate, dt, "sensors.mag.rate"), self.mag.sample),
        ]
        if params.actors or params.obstacles:
            self.outputs.append(("actors", steps_per_period(params.actors_rate, dt, "actors_rate"), self._actors))
        scan_steps = steps_per_period(s.lasers.rate, dt, "sensors.lasers.rate")
        for laser in self.lasers:
            self.outputs.append(("scan", scan_steps, laser.sample))
        if self.cameras:
            cam_steps = steps_per_period(s.cameras.rate, dt, "sensors.cameras.rate")
            for cam in self.cameras:
                self.outputs.append(("image", cam_steps, cam.sample))
        self.enabled: Dict[str, bool] = {name: True for name, _, _ in self.outputs}
        self.script: Optional[SetpointScript] = None
        self.steps = 0
        self._plc_link_start()

    def _plc_link_start(self) -> None:
        """The PLC link's latency: STATE frames wait here until their delivery step (its own
        seeded draws: the same seed, the same delays, after a reset too)."""
        self.plc_link = Latency(self.params.plc.latency,
                                np.random.default_rng([self.params.seed, zlib.crc32(b"plc_link")]))
        self.plc_pending: Deque[Tuple[float, object]] = deque()  # (delivery time, STATE)
        # The PLC's own accelerometer (its standstill monitor): base_link's specific force
        # along x from the velocity change over a PLC cycle, with white noise of its own draws
        self.plc_accel_rng = np.random.default_rng([self.params.seed, zlib.crc32(b"plc_accel")])
        self.plc_prev_v: Optional[Tuple[float, float, float]] = None

    @property
    def t(self) -> float:
        """Sim time [s]."""
        return self.steps * self.dt

    def reset(self, spawn: Optional[Pose2D] = None) -> None:
        """Back to t = 0 with the vehicle at rest at ``spawn`` (default: the configured spawn)."""
        self.steps = 0
        self.world.reset(spawn)
        self.actors = [ActorMotion(a) for a in self.params.actors]
        self.touching = []
        self._move_actors()
        self.plc.reset(0.0)
        self.imu.reset()
        for laser in self.lasers:
            laser.reset()
        self._plc_link_start()

    def step(self) -> List[Tuple[str, object]]:
        """Advance one physics step; returns the samples due at the new time."""
        w = self.world
        if self.steps % self.cycle_steps == 0:
            if self.script is not None:
                self.plc.force_auto(self.t)
                self.plc.setpoint(protocol.SOURCE_AUTO, *self.script.at(self.t))
            m = self.params.measurement
            act = self.plc.cycle(self.t, m.wheel_speed_scale * w.rear_wheel_speed,
                                 m.wheel_speed_scale * w.rear_wheel_rate, self._plc_accel_x())
            w.set_handlebar(act.handlebar + m.handlebar_offset)
            w.set_drive_torque(act.drive_torque)
            w.set_brake(act.brake_torque)
        if self.actors:
            self._move_actors()
        v_before = w.base_state()[2]  # the speed at impact: the contact's step has slowed it already
        w.step()
        self.steps += 1
        t = self.t
        due = []
        touching = w.touching()
        if touching != self.touching:
            for body in touching:
                if body not in self.touching:
                    ev = self._contact(t, body, v_before)
                    self.contacts.append(ev)
                    due.append(("contact", ev))
            self.touching = touching
        for name, period, sampler in self.outputs:
            if self.steps % period == 0 and self.enabled[name]:
                if name == "plc_state" and not self.plc_link.zero:
                    self.plc_pending.append((self.plc_link.deliver_at(t), sampler(t)))
                else:
                    due.append((name, sampler(t)))
        # STATE frames leave at the first step at or after plc_time + the link's delay: a
        # delay below one physics step arrives one step late (10 ms at dt 10 ms)
        while self.plc_pending and self.plc_pending[0][0] <= t + 1e-9:
            due.append(("plc_state", self.plc_pending.popleft()[1]))
        return due

    PLC_ACCEL_NOISE = 0.02  # [m/s^2] white noise of the PLC's accelerometer per cycle

    def _plc_accel_x(self) -> float:
        _, orn, vel, _ = self.world.base_state()
        prev, self.plc_prev_v = self.plc_prev_v, vel
        if prev is None:
            return float("nan")
        k = 1.0 / (self.cycle_steps * self.dt)
        a = ((vel[0] - prev[0]) * k, (vel[1] - prev[1]) * k, (vel[2] - prev[2]) * k + GRAVITY)
        f_x = rotate_inverse(quat_to_rows(orn), a)[0]
        return f_x + self.PLC_ACCEL_NOISE * float(self.plc_accel_rng.standard_normal())

    def _move_actors(self) -> None:
        pos = self.world.base_state()[0]
        for k, (motion, a) in enumerate(zip(self.actors, self.params.actors)):
            before = motion.last
            pose = motion.update(self.t, (pos[0], pos[1]))
            if before is None or (pose.x, pose.y, pose.yaw) == (before.x, before.y, before.yaw):
                continue
            self.world.move_actor(k, pose.x, pose.y, pose.yaw, a.dims[2])
            # an actor does not walk into the vehicle (actors.py): near it (a cheap test of
            # the centres first), a step closer than keep_clear and than before is taken back
            reach = self.vehicle_reach + 0.5 * math.hypot(a.dims[0], a.dims[1]) + a.keep_clear + 0.5
            if (pose.x - pos[0]) ** 2 + (pose.y - pos[1]) ** 2 > reach * reach:
                continue
            gap = self.world.actor_gap(k, a.keep_clear)
            if gap < a.keep_clear:
                self.world.move_actor(k, before.x, before.y, before.yaw, a.dims[2])
                if gap < self.world.actor_gap(k, a.keep_clear) - 1e-9:
                    motion.hold_back()  # it would have come closer: it waits
                    continue
                self.world.move_actor(k, pose.x, pose.y, pose.yaw, a.dims[2])  # along or away: on

    def _contact(self, t: float, body: int, v) -> ContactEvent:
        name, kind = self.world.body_names.get(body, (f"body {body}", "unknown"))
        pos = self.world.base_state()[0]
        return ContactEvent(t, name, kind, (v[0] ** 2 + v[1] ** 2) ** 0.5, (pos[0], pos[1]))

    def _actors(self, t: float) -> List[ActorSample]:
        out = []
        for motion, a in zip(self.actors, self.params.actors):
            p = motion.last if motion.waiting else motion.pose(t)  # waiting: where it stands
            out.append(ActorSample(a.name, a.kind, a.geometry, p.x, p.y, p.yaw, a.dims, p.speed))
        for k, o in enumerate(self.params.obstacles):
            dims = (2.0 * o.size[0], 2.0 * o.size[0], o.size[2]) if o.kind == "cylinder" else tuple(o.size)
            out.append(ActorSample(f"obstacle {k}", "obstacle", o.kind, o.xy[0], o.xy[1], o.yaw, dims, 0.0))
        return out

    def _ground_truth(self, t: float) -> GroundTruth:
        pos, orn, v, w = self.world.base_state()
        return GroundTruth(t, pos, orn, v, w)

    def _joints(self, t: float) -> JointSample:
        names, pos, vel = self.world.joint_positions()
        return JointSample(t, tuple(names), tuple(pos), tuple(vel))

    def _plc_state(self, t: float):
        m = self.params.measurement
        speed = m.wheel_speed_scale * self.world.rear_wheel_speed
        if any(a <= t < b for a, b in m.wheel_speed_dead):
            speed = 0.0
        return self.plc.state(t, speed)

    def close(self) -> None:
        self.world.close()
