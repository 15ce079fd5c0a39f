"""The PyBullet world: ground or terrain, static obstacles, and the Quadrivio ATV.

The vehicle is the URDF generated from ``vehicle.yaml``. Each physics step the world
applies, in the joints' own frames:

* suspension (prismatic joints, axis z): ``F = -P - k q - c q'`` with ``P`` the static
  corner load (so the static position is ``q = 0``), ``k``, ``c`` from ``vehicle.yaml``;
* wheel torques: drive torque split over the driven wheels, engine braking, rolling
  resistance ``Crr N r tanh(w / w0)`` opposing rotation; wheels on one shaft (the solid
  rear axle; front and rear in locked 4WD) are tied by gear constraints;
* brakes: a velocity motor with target 0 whose force limit is the brake torque, i.e.
  Coulomb friction solved implicitly by Bullet (holds the vehicle still on a slope);
* steering: each front knuckle is position-controlled to its Ackermann angle.

Poses returned by the world are of the ``base_link`` frame (rear axle centre), not of
PyBullet's base centre of mass.
"""

from __future__ import annotations

import math
import os
import sys
import tempfile
from dataclasses import dataclass
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
import pybullet
from pybullet_utils import bullet_client

from quadrivio_config import ConfigError, param
from quadrivio_description.frames import matrix_from_quaternion, quaternion_from_rpy, rpy_from_quaternion
from quadrivio_description.kinematics import ackermann_wheel_angles
from quadrivio_description.urdf import CORNERS
from quadrivio_description.vehicle import GRAVITY, VehicleParams

from quadrivio_terrain.terrain import Heightfield, TerrainParams, build_heightfield

Vec3 = Tuple[float, float, float]
Quat = Tuple[float, float, float, float]  # x, y, z, w (PyBullet order)


def _direct_client():
    """A DIRECT PyBullet client, without the "argv[0]=" its C code prints to the process's
    stdout on every connect (two lines a run in every campaign log)."""
    sys.stdout.flush()
    saved = os.dup(1)
    try:
        with open(os.devnull, "w") as null:
            os.dup2(null.fileno(), 1)
            return bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
    finally:
        os.dup2(saved, 1)
        os.close(saved)


@dataclass(frozen=True)
class PhysicsParams:
    dt: float = param(0.01, lo=1e-4, hi=0.05, unit="s", doc="fixed physics step")
    solver_iterations: int = param(10, lo=1, hi=500, doc="constraint solver iterations per step")
    steer_force: float = param(3000.0, lo=1.0, hi=1e6, unit="N m", doc="steering actuator force limit per knuckle")
    steer_gain: float = param(0.6, lo=0.01, hi=1.0, doc="Bullet position gain of the knuckle position motors")


@dataclass(frozen=True)
class Obstacle:
    kind: str = param(choices=("box", "cylinder"), doc="shape")
    xy: Tuple[float, float] = param(unit="m", doc="centre in the map frame")
    size: Tuple[float, float, float] = param(unit="m",
                                             doc="box: length, width, height; cylinder: radius, unused, height")
    yaw: float = param(0.0, unit="rad", doc="box heading")


@dataclass(frozen=True)
class Pose2D:
    x: float = param(0.0, lo=-1e5, hi=1e5, unit="m")
    y: float = param(0.0, lo=-1e5, hi=1e5, unit="m")
    yaw: float = param(0.0, lo=-10.0, hi=10.0, unit="rad")


def quat_to_matrix(q: Sequence[float]) -> np.ndarray:
    """Rotation matrix of a unit quaternion ``(x, y, z, w)``."""
    return np.array(quat_to_rows(q))


def quat_to_rows(q: Sequence[float]):
    """Rotation matrix of a unit quaternion ``(x, y, z, w)`` as rows (no numpy)."""
    return matrix_from_quaternion(*q)


def rotate_inverse(R: List[List[float]], v: Sequence[float]) -> Vec3:
    """``R^T v`` for a rotation given as rows (world vector into the body frame)."""
    return (R[0][0] * v[0] + R[1][0] * v[1] + R[2][0] * v[2], R[0][1] * v[0] + R[1][1] * v[1] + R[2][1] * v[2],
            R[0][2] * v[0] + R[1][2] * v[1] + R[2][2] * v[2])


def quat_to_rpy(q: Sequence[float]) -> Vec3:
    """Roll, pitch, yaw (ZYX) of a quaternion ``(x, y, z, w)`` [rad]."""
    return rpy_from_quaternion(*q)


def fixed_frames(urdf_text: str, root: str = "base_link") -> Dict[str, Tuple[Vec3, Quat]]:
    """Pose in ``root`` of every link attached to it through fixed joints only."""
    import xml.etree.ElementTree as ET

    robot = ET.fromstring(urdf_text)
    children: Dict[str, List[Tuple[str, Vec3, Quat]]] = {}
    for j in robot.iter("joint"):
        if j.get("type") != "fixed":
            continue
        origin = j.find("origin")
        xyz = tuple(map(float, origin.get("xyz", "0 0 0").split())) if origin is not None else (0.0, 0.0, 0.0)
        rpy = tuple(map(float, origin.get("rpy", "0 0 0").split())) if origin is not None else (0.0, 0.0, 0.0)
        children.setdefault(j.find("parent").get("link"), []).append((j.find("child").get("link"), xyz, quaternion_from_rpy(*rpy)))
    frames: Dict[str, Tuple[Vec3, Quat]] = {}
    stack = [(root, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0))]
    while stack:
        parent, p0, q0 = stack.pop()
        for child, xyz, q in children.get(parent, []):
            p, o = pybullet.multiplyTransforms(p0, q0, xyz, q)
            frames[child] = (tuple(p), tuple(o))
            stack.append((child, p, o))
    return frames


def strip_fixed_leaves(urdf_text: str) -> str:
    """The URDF without its fixed leaf links (sensor frames) and their joints.

    Each link is a body PyBullet integrates; the seven massless sensor frames cost 17 %
    of a physics step. Their poses come from :func:`fixed_frames` instead. (PyBullet's
    own URDF_MERGE_FIXED_LINKS would do this but drops the base link's inertial offset.)
    """
    import xml.etree.ElementTree as ET

    robot = ET.fromstring(urdf_text)
    while True:
        parents = {j.find("parent").get("link") for j in robot.findall("joint")}
        leaves = [j for j in robot.findall("joint")
                  if j.get("type") == "fixed" and j.find("child").get("link") not in parents]
        if not leaves:
            break
        names = {j.find("child").get("link") for j in leaves}
        for j in leaves:
            robot.remove(j)
        for link in robot.findall("link"):
            if link.get("name") in names:
                robot.remove(link)
    return ET.tostring(robot, encoding="unicode")


class World:
    """One PyBullet physics client holding the ground, obstacles and one vehicle."""

    def __init__(self, vehicle: VehicleParams, urdf_text: str, physics: PhysicsParams,
                 terrain: TerrainParams, rng: np.random.Generator,
                 obstacles: Sequence[Obstacle] = (), spawn: Pose2D = Pose2D(), map_blocks: Sequence = (),
                 block_height: float = 1.5, actors: Sequence = (), frame=None) -> None:
        """``map_blocks``: obstacles made from a map's occupied cells
        (:func:`quadrivio_navigation.maps.obstacles_from_grid`), ``block_height`` [m] tall;
        ``actors``: :class:`quadrivio_sim.actors.ActorParams`, bodies moved by :meth:`move_actor`;
        ``frame``: the site's local frame, which places a GeoTIFF DEM (``terrain.kind: geotiff``)."""
        self.v = vehicle
        self.physics = physics
        self.terrain = terrain
        self.dt = physics.dt
        self.pb = _direct_client()
        # Hot paths call pybullet directly with this id: BulletClient wraps every call in
        # a new functools.partial (about 2 ms per simulated second).
        self.cid = self.pb._client
        self.pb.setPhysicsEngineParameter(fixedTimeStep=physics.dt, numSolverIterations=physics.solver_iterations,
                                          numSubSteps=0, deterministicOverlappingPairs=1)
        self.pb.setGravity(0.0, 0.0, -GRAVITY)
        self.heightfield: Optional[Heightfield] = build_heightfield(terrain, rng, frame)
        self.ground = self._make_ground(self.pb)
        self.obstacle_ids = [self._make_obstacle(self.pb, o) for o in obstacles]
        meshes = self._block_meshes(map_blocks, block_height)
        self.map_ids = [self._make_mesh(self.pb, v, i) for v, i in meshes]
        # A second, static client with the same ground and obstacles and no vehicle:
        # sensor rays are cast there (3-5x cheaper than among the vehicle's links).
        self.rays = _direct_client()
        self.rays_cid = self.rays._client
        self._make_ground(self.rays)
        for o in obstacles:
            self._make_obstacle(self.rays, o)
        for v, i in meshes:
            self._make_mesh(self.rays, v, i)
        # Actors: one body in each client (the vehicle hits one, the sensors see the other)
        self.actor_ids = [(self._make_actor(self.pb, a), self._make_actor(self.rays, a)) for a in actors]
        # Every body but the ground, by id in the physics client: (name, kind) for contacts
        self.body_names: Dict[int, Tuple[str, str]] = {}
        for k, (o, b) in enumerate(zip(obstacles, self.obstacle_ids)):
            self.body_names[b] = (f"obstacle {k} ({o.kind} at {o.xy[0]:g}, {o.xy[1]:g})", "obstacle")
        for k, b in enumerate(self.map_ids):
            self.body_names[b] = (f"map obstacles (tile {k})", "map")
        for a, (b, _) in zip(actors, self.actor_ids):
            self.body_names[b] = (a.name, a.kind)
        self.frames = fixed_frames(urdf_text)
        self.robot = self._load_vehicle(urdf_text)
        self._index_joints()
        self._configure_dynamics()
        self._filter_tyre_contacts()
        self.spawn = spawn
        self.reset(spawn)

    # ----------------------------------------------------------------- building
    def _make_ground(self, pb) -> int:
        if self.heightfield is None:
            shape = pb.createCollisionShape(pybullet.GEOM_PLANE)
            ground = pb.createMultiBody(0, shape)
        else:
            hf = self.heightfield
            rows, cols = hf.shape
            # Bullet: numHeightfieldRows samples along x (our columns), data[x + y * nx].
            shape = pb.createCollisionShape(
                pybullet.GEOM_HEIGHTFIELD, meshScale=[hf.res, hf.res, 1.0],
                heightfieldData=hf.z.ravel().tolist(), numHeightfieldRows=cols, numHeightfieldColumns=rows)
            ground = pb.createMultiBody(0, shape)
            # Bullet centres the heightfield on its height range: shift it back.
            pb.resetBasePositionAndOrientation(ground, [0.0, 0.0, 0.5 * (hf.z.min() + hf.z.max())], [0, 0, 0, 1])
        pb.changeDynamics(ground, -1, lateralFriction=self.terrain.friction, restitution=0.0)
        pb.changeVisualShape(ground, -1, rgbaColor=[0.45, 0.42, 0.33, 1.0])  # dirt (camera images)
        return ground

    def _make_obstacle(self, pb, o: Obstacle) -> int:
        if o.kind == "box":
            shape = pb.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.5 * o.size[0], 0.5 * o.size[1], 0.5 * o.size[2]])
        else:
            shape = pb.createCollisionShape(pybullet.GEOM_CYLINDER, radius=o.size[0], height=o.size[2])
        z0 = self.ground_height(*o.xy)
        body = pb.createMultiBody(0, shape, basePosition=[o.xy[0], o.xy[1], z0 + 0.5 * o.size[2]],
                                  baseOrientation=pb.getQuaternionFromEuler([0.0, 0.0, o.yaw]))
        pb.changeVisualShape(body, -1, rgbaColor=[0.3, 0.5, 0.25, 1.0] if o.kind == "cylinder" else [0.6, 0.6, 0.6, 1.0])
        return body

    def _make_actor(self, pb, a) -> int:
        length, width, height = a.dims
        if a.geometry == "cylinder":
            shape = pb.createCollisionShape(pybullet.GEOM_CYLINDER, radius=0.5 * length, height=height)
        else:
            shape = pb.createCollisionShape(pybullet.GEOM_BOX, halfExtents=[0.5 * length, 0.5 * width, 0.5 * height])
        x, y = a.waypoints[0]
        body = pb.createMultiBody(0, shape, basePosition=[x, y, self.ground_height(x, y) + 0.5 * height])
        colour = {"person": [0.8, 0.2, 0.2, 1.0], "animal": [0.5, 0.35, 0.2, 1.0]}.get(a.kind, [0.2, 0.3, 0.7, 1.0])
        pb.changeVisualShape(body, -1, rgbaColor=colour)
        return body

    def move_actor(self, k: int, x: float, y: float, yaw: float, height: float) -> None:
        """Put actor ``k`` at (x, y, yaw) on the ground (both clients)."""
        q = (0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw))
        pos = (x, y, self.ground_height(x, y) + 0.5 * height)
        for body, cid in zip(self.actor_ids[k], (self.cid, self.rays_cid)):
            pybullet.resetBasePositionAndOrientation(body, pos, q, physicsClientId=cid)

    def actor_gap(self, k: int, within: float) -> float:
        """The distance from actor ``k``'s body to the vehicle's (body and tyres) as they stand,
        when under ``within`` [m]; inf otherwise (0 or less: touching)."""
        pts = pybullet.getClosestPoints(self.actor_ids[k][0], self.robot, within, physicsClientId=self.cid)
        return min((c[8] for c in pts if c[4] not in self.wheels), default=math.inf)  # the spheres meet the ground only

    def touching(self) -> List[int]:
        """The bodies other than the ground that touch the vehicle now (their ids, sorted)."""
        pts = pybullet.getContactPoints(bodyA=self.robot, physicsClientId=self.cid)
        return sorted({c[2] for c in pts if c[2] != self.ground and c[2] != self.robot})

    TILE = 25.0  # [m] map obstacles are merged into one static mesh per tile of this size

    def _block_meshes(self, blocks: Sequence, height: float) -> List[Tuple[list, list]]:
        """Triangle meshes (vertices, indices), one per tile, of the map's obstacles: boxes
        as boxes, cylinders as 16-sided prisms around them, standing on the ground (sunk
        0.2 m into it so that a slope leaves no gap). One static mesh per tile keeps a map of
        thousands of obstacles as cheap for Bullet's collision and ray tests as a few bodies
        (a compound shape holds at most 16 children)."""
        tiles: Dict[Tuple[int, int], Tuple[list, list]] = {}
        ring = [(math.cos(2 * math.pi * k / 16), math.sin(2 * math.pi * k / 16)) for k in range(16)]
        scale = 1.0 / math.cos(math.pi / 16)  # the polygon circumscribes the circle
        for b in blocks:
            if b.kind == "box":
                c, s_ = math.cos(b.yaw), math.sin(b.yaw)
                hx, hy = 0.5 * b.size_x, 0.5 * b.size_y
                outline = [(b.x + c * dx - s_ * dy, b.y + s_ * dx + c * dy)
                           for dx, dy in ((-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy))]
            else:
                r = 0.5 * b.size_x * scale
                outline = [(b.x + r * cx, b.y + r * cy) for cx, cy in ring]
            z0 = min(self.ground_height(x, y) for x, y in outline) - 0.2
            z1 = max(self.ground_height(x, y) for x, y in outline) + height
            key = (int(math.floor(b.x / self.TILE)), int(math.floor(b.y / self.TILE)))
            verts, idx = tiles.setdefault(key, ([], []))
            n, base = len(outline), len(verts)
            verts += [[x, y, z0] for x, y in outline] + [[x, y, z1] for x, y in outline]
            for k in range(n):  # sides
                a, b_ = k, (k + 1) % n
                idx += [base + a, base + b_, base + n + b_, base + a, base + n + b_, base + n + a]
            for k in range(1, n - 1):  # bottom and top fans
                idx += [base, base + k + 1, base + k, base + n, base + n + k, base + n + k + 1]
        return list(tiles.values())

    @staticmethod
    def _make_mesh(pb, vertices: list, indices: list) -> int:
        shape = pb.createCollisionShape(pybullet.GEOM_MESH, vertices=vertices, indices=indices)
        body = pb.createMultiBody(0, shape)
        pb.changeVisualShape(body, -1, rgbaColor=[0.3, 0.5, 0.25, 1.0])
        return body

    def _load_vehicle(self, urdf_text: str) -> int:
        with tempfile.TemporaryDirectory(prefix="quadrivio_urdf_") as tmp:
            path = os.path.join(tmp, "vehicle.urdf")
            with open(path, "w", encoding="utf-8") as fh:
                fh.write(strip_fixed_leaves(urdf_text))
            try:
                return self.pb.loadURDF(path, flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
            except pybullet.error as exc:
                raise ConfigError(f"PyBullet could not load the vehicle URDF: {exc}") from exc

    def _filter_tyre_contacts(self) -> None:
        """The wheels' spheres meet the ground only, the tyres' cylinders (on the front
        knuckles and rear hubs, urdf.py) everything but the ground: a sphere of the tyre's
        radius reaches 0.19 m past the tyre's outer face sideways, and touched a person
        0.17 m from the side of the vehicle."""
        for corner in CORNERS:
            carrier = self.link_index.get(f"{corner}_knuckle" if corner.startswith("front") else f"{corner}_hub")
            if carrier is not None:
                self.pb.setCollisionFilterPair(self.robot, self.ground, carrier, -1, 0)
        for body in self.body_names:
            for j in self.wheels:
                self.pb.setCollisionFilterPair(self.robot, body, j, -1, 0)

    def _index_joints(self) -> None:
        pb = self.pb
        self.joint_index: Dict[str, int] = {}
        self.link_index: Dict[str, int] = {pb.getBodyInfo(self.robot)[0].decode(): -1}
        self.movable: List[int] = []
        self.joint_names: List[str] = []
        for j in range(pb.getNumJoints(self.robot)):
            info = pb.getJointInfo(self.robot, j)
            name, kind, child = info[1].decode(), info[2], info[12].decode()
            self.joint_index[name] = j
            self.link_index[child] = j
            if kind != pybullet.JOINT_FIXED:
                self.movable.append(j)
                self.joint_names.append(name)
        corners = CORNERS
        try:
            self.susp = [self.joint_index[f"{c}_suspension_joint"] for c in corners]
            self.wheels = [self.joint_index[f"{c}_wheel_joint"] for c in corners]
            self.steer = [self.joint_index[f"{c}_steer_joint"] for c in corners[:2]]
        except KeyError as exc:
            raise ConfigError(f"the vehicle URDF lacks the joint {exc}; it must come from "
                              "quadrivio_description's generator or follow its joint names") from exc
        drive = self.v.drivetrain.drive
        self.driven = self.wheels if drive in ("4wd", "4wd_locked") else self.wheels[2:]
        # Wheels on one shaft turn together (see _lock_shafts).
        fl, fr, rl, rr = self.wheels
        self.locked_pairs = [(rl, rr)] + ([(fl, fr), (fl, rl)] if drive == "4wd_locked" else [])
        # Position of each joint of interest inside the getJointStates result.
        self._state_ids = self.susp + self.wheels + self.steer
        self._torque_ids = self.susp + self.wheels
        self._spring_k = [self.v.suspension.front.stiffness] * 2 + [self.v.suspension.rear.stiffness] * 2
        self._spring_c = [self.v.suspension.front.damping] * 2 + [self.v.suspension.rear.damping] * 2
        # Preload: static corner load of the sprung mass, so that q = 0 at rest.
        self._preload = [self.v.corner_static_load(True)] * 2 + [self.v.corner_static_load(False)] * 2
        info = pb.getDynamicsInfo(self.robot, -1)
        self._com_in_base = (tuple(info[3]), tuple(info[4]))  # base COM frame in base_link
        self._base_in_com = pb.invertTransform(*self._com_in_base)

    def _configure_dynamics(self) -> None:
        pb, w = self.pb, self.v.wheels
        # No artificial damping (PyBullet's default 0.04): losses are modelled explicitly.
        for link in [-1] + list(range(pb.getNumJoints(self.robot))):
            pb.changeDynamics(self.robot, link, linearDamping=0.0, angularDamping=0.0)
        for j in self.wheels:
            pb.changeDynamics(self.robot, j, lateralFriction=w.lateral_friction, rollingFriction=w.rolling_friction,
                              spinningFriction=w.spinning_friction, contactStiffness=w.contact_stiffness,
                              contactDamping=w.contact_damping, restitution=0.0)
        # Joints are driven by explicit forces: switch off Bullet's default velocity motors.
        pb.setJointMotorControlArray(self.robot, self.susp, pybullet.VELOCITY_CONTROL, forces=[0.0] * 4)
        pb.setJointMotorControlArray(self.robot, self.wheels, pybullet.VELOCITY_CONTROL, forces=[0.0] * 4)
        self._lock_shafts()
        self._brake_torque = 0.0
        self._handlebar = None

    def _lock_shafts(self) -> None:
        """The ATV's rear wheels sit on a solid axle (no rear differential): a wheel that
        lifts off a bump cannot spin away with the drive torque, as it would through an
        open differential. In ``4wd`` the front wheels take half the torque through an
        open front differential (equal torque per side); ``4wd_locked`` also locks the
        front differential and couples the front and rear shafts (Table 1's "locked 4WD").
        Each lock is a Bullet gear constraint, ratio -1 meaning "same direction"."""
        pb = self.pb
        for a, b in self.locked_pairs:
            c = pb.createConstraint(self.robot, a, self.robot, b, jointType=pybullet.JOINT_GEAR, jointAxis=[0, 1, 0],
                                    parentFramePosition=[0, 0, 0], childFramePosition=[0, 0, 0])
            pb.changeConstraint(c, gearRatio=-1, maxForce=self.v.drivetrain.axle_torque_limit)

    # ------------------------------------------------------------------ control
    def reset(self, spawn: Optional[Pose2D] = None) -> None:
        """Put the vehicle at rest at ``spawn`` (default: the initial spawn) on the ground,
        its attitude following the terrain: with the ground's slope ``s_x`` along the
        heading and ``s_y`` to the left, ``pitch = -atan(s_x)`` (nose up uphill, REP-103)
        and ``roll = atan(s_y)``."""
        spawn = spawn or self.spawn
        pb = self.pb
        x, y = spawn.x, spawn.y
        gx, gy = (0.0, 0.0) if self.heightfield is None else self.heightfield.gradient(x, y)
        c, s_ = math.cos(spawn.yaw), math.sin(spawn.yaw)
        pitch = -math.atan(gx * c + gy * s_)
        roll = math.atan(-gx * s_ + gy * c)
        q = pb.getQuaternionFromEuler([roll, pitch, spawn.yaw])
        # base_link sits a wheel radius above the ground along the ground's normal.
        normal = np.array([-gx, -gy, 1.0]) / math.sqrt(gx * gx + gy * gy + 1.0)
        pos = np.array([x, y, self.ground_height(x, y)]) + (self.v.wheel_radius + 0.02) * normal
        self.set_base_link_pose(tuple(pos.tolist()), q)
        pb.resetBaseVelocity(self.robot, [0, 0, 0], [0, 0, 0])
        for j in self.movable:
            pb.resetJointState(self.robot, j, 0.0, 0.0)
        self.drive_torque = 0.0
        self.set_brake(0.0)
        self._handlebar = None
        self.set_handlebar(0.0)
        self._read_joints()

    def set_handlebar(self, angle: float) -> None:
        """Set the knuckles to the Ackermann angles of handlebar ``angle`` [rad]."""
        if angle == self._handlebar:
            return
        self._handlebar = angle
        left, right = ackermann_wheel_angles(self.v.steering.ratio * angle, self.v.wheelbase, self.v.front_track)
        pybullet.setJointMotorControlArray(
            self.robot, self.steer, pybullet.POSITION_CONTROL, targetPositions=[left, right],
            forces=[self.physics.steer_force] * 2, positionGains=[self.physics.steer_gain] * 2,
            physicsClientId=self.cid)

    def set_drive_torque(self, torque: float) -> None:
        """Total drive torque at the driven wheels [N m] (engine braking included), applied every step."""
        self.drive_torque = torque

    def set_brake(self, torque: float) -> None:
        """Total brake torque over the four wheels [N m]."""
        torque = max(0.0, torque)
        if abs(torque - self._brake_torque) < 1e-3 and torque != 0.0:
            return
        self._brake_torque = torque
        pybullet.setJointMotorControlArray(self.robot, self.wheels, pybullet.VELOCITY_CONTROL,
                                           targetVelocities=[0.0] * 4, forces=[0.25 * torque] * 4,
                                           physicsClientId=self.cid)

    # --------------------------------------------------------------- stepping
    def _read_joints(self) -> None:
        states = pybullet.getJointStates(self.robot, self._state_ids, physicsClientId=self.cid)
        self.q = [s[0] for s in states]
        self.qd = [s[1] for s in states]
        self._base_cache = None

    def step(self) -> None:
        """Apply suspension forces and wheel torques, then advance the physics by ``dt``."""
        q, qd = self.q, self.qd
        forces = [-self._preload[i] - self._spring_k[i] * q[i] - self._spring_c[i] * qd[i] for i in range(4)]
        n_driven = len(self.driven)
        load = 0.25 * self.v.body.mass * GRAVITY
        crr = self.terrain.rolling_resistance * load * self.v.wheel_radius
        for k, j in enumerate(self.wheels):
            w = qd[4 + k]
            tau = -crr * math.tanh(w / 0.5)
            if j in self.driven:
                tau += self.drive_torque / n_driven
            forces.append(tau)
        pybullet.setJointMotorControlArray(self.robot, self._torque_ids, pybullet.TORQUE_CONTROL, forces=forces,
                                           physicsClientId=self.cid)
        pybullet.stepSimulation(physicsClientId=self.cid)
        self._read_joints()

    # ------------------------------------------------------------------ state
    @property
    def rear_wheel_rate(self) -> float:
        """Mean angular rate of the rear wheels [rad/s] (the PLC's wheel encoder)."""
        return 0.5 * (self.qd[6] + self.qd[7])

    @property
    def rear_wheel_speed(self) -> float:
        """Rear wheel speed = rate x unloaded radius [m/s]."""
        return self.rear_wheel_rate * self.v.wheel_radius

    @property
    def steer_angles(self) -> Tuple[float, float]:
        return self.q[8], self.q[9]

    @property
    def suspension_positions(self) -> List[float]:
        return list(self.q[:4])

    def joint_positions(self) -> Tuple[List[str], List[float], List[float]]:
        """Names, positions and velocities of every movable joint (for /joint_states)."""
        states = self.pb.getJointStates(self.robot, self.movable)
        return self.joint_names, [s[0] for s in states], [s[1] for s in states]

    def base_state(self) -> Tuple[Vec3, Quat, Vec3, Vec3]:
        """``base_link`` position, orientation (x, y, z, w), linear velocity of its origin and
        angular velocity, all in the world (map) frame. Cached until the next step."""
        if self._base_cache is None:
            com_pos, com_orn = pybullet.getBasePositionAndOrientation(self.robot, physicsClientId=self.cid)
            v_com, w = pybullet.getBaseVelocity(self.robot, physicsClientId=self.cid)
            pos, orn = pybullet.multiplyTransforms(com_pos, com_orn, *self._base_in_com)
            # Velocity of the base_link origin: v = v_com + w x (p - p_com).
            rx, ry, rz = pos[0] - com_pos[0], pos[1] - com_pos[1], pos[2] - com_pos[2]
            wx, wy, wz = w
            v = (v_com[0] + wy * rz - wz * ry, v_com[1] + wz * rx - wx * rz, v_com[2] + wx * ry - wy * rx)
            self._base_cache = (tuple(pos), tuple(orn), v, tuple(w))
        return self._base_cache

    def set_base_link_pose(self, pos: Vec3, orn: Quat) -> None:
        com_pos, com_orn = self.pb.multiplyTransforms(pos, orn, *self._com_in_base)
        self.pb.resetBasePositionAndOrientation(self.robot, com_pos, com_orn)
        self._base_cache = None

    def link_state(self, link: str) -> Tuple[Vec3, Quat, Vec3, Vec3]:
        """World position, orientation, linear and angular velocity of a frame fixed to
        ``base_link`` (a sensor frame): ``p = p_b + R_b r``, ``v = v_b + w x (R_b r)``."""
        pos, orn, v, w = self.base_state()
        if link == "base_link":
            return pos, orn, v, w
        try:
            r, q = self.frames[link]
        except KeyError:
            raise KeyError(f"no frame '{link}' fixed to base_link in the vehicle URDF") from None
        p_s, o_s = pybullet.multiplyTransforms(pos, orn, r, q)
        rx, ry, rz = p_s[0] - pos[0], p_s[1] - pos[1], p_s[2] - pos[2]
        wx, wy, wz = w
        v_s = (v[0] + wy * rz - wz * ry, v[1] + wz * rx - wx * rz, v[2] + wx * ry - wy * rx)
        return p_s, o_s, v_s, w

    def wheel_contacts(self) -> List[bool]:
        """Whether each wheel (front left, front right, rear left, rear right) touches the ground."""
        return [bool(self.pb.getContactPoints(self.robot, self.ground, linkIndexA=j)) for j in self.wheels]

    def ground_height(self, x: float, y: float) -> float:
        return 0.0 if self.heightfield is None else self.heightfield.height(x, y)

    def ray_batch(self, starts, ends) -> List[float]:
        """Hit fraction of each ray (1.0: no hit) against ground and obstacles (world frame);
        ``starts`` and ``ends`` are (n, 3) arrays or sequences of points."""
        # numThreads=1: Bullet's default (-1) costs 50 % more per 271-ray batch here.
        hits = pybullet.rayTestBatch(starts, ends, numThreads=1, physicsClientId=self.rays_cid)
        return [h[2] if h[0] != -1 else 1.0 for h in hits]

    def close(self) -> None:
        for client in (self.pb, self.rays):
            try:
                client.disconnect()
            except pybullet.error:
                pass
