"""Scenarios: one YAML file per experiment (``scenarios/NAME.yaml`` or any path).

Sections (all optional but ``name``), each overriding the config of the node that reads
it at start-up (``/scenario/<section>``)::

    name, description, seed
    vehicle:        quadrivio_description/config/vehicle.yaml (or sim.launch's vehicle_file):
                    drive train, masses, limits; every node of the run reads them
    sim:            quadrivio_sim/config/sim.yaml         (terrain, spawn, obstacles, physics)
    sensors:        gps | imu | mag | laser_front | laser_rear -> quadrivio_sim/config/<sensor>.yaml
    localization:   quadrivio_localization/config/localization.yaml
    path:           quadrivio_navigation/config/path.yaml     (kind goal: the planner drives to path.goal)
    follower:       quadrivio_navigation/config/follower.yaml
    map:            quadrivio_navigation/config/map_server.yaml (the map: published on /map, obstacles in the simulator)
    planner:        quadrivio_navigation/config/planner.yaml
    guard:          quadrivio_navigation/config/guard.yaml (the obstacle guard: fields, scanners, operating zone)
    local_layer:    quadrivio_navigation/config/local_layer.yaml (the local obstacle grid the planner replans on)
    actors:         people, animals and vehicles the simulator moves (quadrivio_sim.actors)
    excitation:     quadrivio_navigation/config/excitation.yaml (open-loop steps and sweeps for
                    `calibrate` instead of navigation; run.end must be duration)
    run:            this module's RunParams (real-time factor, time limit, end)

:func:`load_scenario` validates every section against the same dataclasses the nodes
use, so a typo or an out-of-range value stops the experiment before anything starts,
with the file, the key and the value in the message.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any, Dict, Tuple

from quadrivio_config import ConfigError, from_mapping, load_yaml, param, replace_nested


@dataclass(frozen=True)
class RunParams:
    rtf: float = param(2.0, lo=0.0, hi=100.0, doc="real-time factor of the run (0: as fast as possible)")
    max_duration: float = param(240.0, lo=1.0, hi=1e6, unit="s", doc="sim time after which the run is stopped")
    end: str = param("path_done", choices=("path_done", "duration"),
                     doc="path_done: when the follower is done (or aborts); duration: at max_duration")
    initial_mode: str = param("AUTO", choices=("SAFE", "MANUAL", "AUTO"), doc="PLC mode requested at start")
    gps_nmea: bool = param(False, doc="GPS through NMEA and the real driver")


SECTIONS = ("vehicle", "sim", "sensors", "localization", "path", "follower", "map", "planner", "guard", "local_layer",
            "actors", "excitation", "run")
SENSORS = ("gps", "imu", "mag", "laser_front", "laser_rear", "camera_left", "camera_right")


@dataclass(frozen=True)
class Scenario:
    name: str
    path: str  # the YAML file
    seed: int
    description: str
    data: Dict[str, Any]  # the whole file, as loaded
    run: RunParams


def scenarios_dir() -> str:
    here = os.path.dirname(os.path.abspath(__file__))
    return os.path.normpath(os.path.join(here, "..", "..", "scenarios"))


def resolve(name_or_path: str) -> str:
    """A scenario name from ``scenarios/`` or a path to a YAML file."""
    if os.path.isfile(name_or_path):
        return os.path.abspath(name_or_path)
    candidate = os.path.join(scenarios_dir(), name_or_path + ("" if name_or_path.endswith(".yaml") else ".yaml"))
    if os.path.isfile(candidate):
        return candidate
    known = sorted(f[:-5] for f in os.listdir(scenarios_dir()) if f.endswith(".yaml"))
    raise ConfigError(f"scenario '{name_or_path}': no such file, and not one of {', '.join(known)}")


def _validators():
    """(section path, dataclass, defaults file) of every node a scenario can configure."""
    from quadrivio_description.vehicle import VehicleParams, default_vehicle_file
    from quadrivio_localization.params import LocalizerParams
    from quadrivio_navigation.excitation import ExcitationParams
    from quadrivio_navigation.follower import FollowerConfig
    from quadrivio_navigation.guard import GuardParams
    from quadrivio_navigation.local_layer import LocalLayerParams
    from quadrivio_navigation.maps import MapParams
    from quadrivio_navigation.paths import PathParams
    from quadrivio_navigation.planning import PlannerParams
    from quadrivio_sim.adapter_params import (CameraAdapterParams, GpsAdapterParams, ImuAdapterParams,
                                              LaserAdapterParams, MagAdapterParams)
    from quadrivio_sim.paths import package_file as sim_file
    from quadrivio_sim.simulator import SimParams

    def pkg(name: str, *parts: str) -> str:
        from quadrivio_description.paths import ros_package_path
        return os.path.join(ros_package_path(name), *parts)

    yield "vehicle", VehicleParams, default_vehicle_file()
    yield "sim", SimParams, sim_file("config", "sim.yaml")
    for sensor, cls, cfg in (("gps", GpsAdapterParams, "gps.yaml"), ("imu", ImuAdapterParams, "imu.yaml"),
                             ("mag", MagAdapterParams, "mag.yaml"), ("laser_front", LaserAdapterParams, "laser.yaml"),
                             ("laser_rear", LaserAdapterParams, "laser.yaml"),
                             ("camera_left", CameraAdapterParams, "camera.yaml"),
                             ("camera_right", CameraAdapterParams, "camera.yaml")):
        yield f"sensors/{sensor}", cls, sim_file("config", cfg)
    yield "localization", LocalizerParams, pkg("quadrivio_localization", "config", "localization.yaml")
    yield "path", PathParams, pkg("quadrivio_navigation", "config", "path.yaml")
    yield "follower", FollowerConfig, pkg("quadrivio_navigation", "config", "follower.yaml")
    yield "map", MapParams, pkg("quadrivio_navigation", "config", "map_server.yaml")
    yield "planner", PlannerParams, pkg("quadrivio_navigation", "config", "planner.yaml")
    yield "guard", GuardParams, pkg("quadrivio_navigation", "config", "guard.yaml")
    yield "local_layer", LocalLayerParams, pkg("quadrivio_navigation", "config", "local_layer.yaml")
    yield "excitation", ExcitationParams, pkg("quadrivio_navigation", "config", "excitation.yaml")


def _section(data: Dict[str, Any], path: str) -> Any:
    node: Any = data
    for part in path.split("/"):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def _defaults(cls, cfg: str):
    """The node's defaults from its config file, keeping only the dataclass's own keys."""
    import dataclasses

    raw = load_yaml(cfg)
    names = {f.name for f in dataclasses.fields(cls)}
    return from_mapping(cls, {k: v for k, v in raw.items() if k in names}, cfg)


def load_scenario(name_or_path: str) -> Scenario:
    path = resolve(name_or_path)
    data = load_yaml(path)
    unknown = sorted(set(data) - set(SECTIONS) - {"name", "description", "seed"})
    if unknown:
        raise ConfigError(f"{path}: unknown section(s) {', '.join(unknown)}; sections: name, description, seed, "
                          f"{', '.join(SECTIONS)}")
    if not isinstance(data.get("name"), str) or not data["name"]:
        raise ConfigError(f"{path}: 'name' is missing")
    seed = data.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ConfigError(f"{path}: 'seed' = {seed!r} must be a non-negative integer")
    sensors = data.get("sensors") or {}
    if not isinstance(sensors, dict) or set(sensors) - set(SENSORS):
        raise ConfigError(f"{path}: 'sensors' may only configure {', '.join(SENSORS)}")
    checked = {}
    for section, cls, cfg in _validators():
        over = _section(data, section)
        if over is not None:
            checked[section] = replace_nested(_defaults(cls, cfg), over, f"{path}: {section.replace('/', '.')}")
    run = from_mapping(RunParams, data.get("run") or {}, path, "run")
    if "excitation" in data:
        from quadrivio_navigation.excitation import build

        exc_params = checked.get("excitation")
        if exc_params is None:  # an empty section: the defaults
            exc_params = next(_defaults(cls, cfg) for sec, cls, cfg in _validators() if sec == "excitation")
        try:
            program = build(exc_params)
        except ConfigError as exc:
            raise ConfigError(f"{path}: {exc}") from exc
        if run.end != "duration" or run.max_duration < program.duration + 1.0:
            raise ConfigError(f"{path}: an excitation program has no follower to say it is done: set run.end: "
                              f"duration and run.max_duration >= {program.duration + 1.0:.1f} s (the program "
                              f"lasts {program.duration:.1f} s)")
    from quadrivio_sim.actors import load_actors

    actors = load_actors(data.get("actors"), path)  # ConfigError naming the actor and the key
    if checked.get("guard") is not None and checked["guard"].zone:
        _check_zone_holds_start(data, checked["guard"].zone, path)
    _check_map(data, path)
    s = Scenario(data["name"], path, seed, str(data.get("description", "")), data, run)
    if actors:
        _check_actors_clear_of_start(s, actors)
    return s


def _check_zone_holds_start(data: Dict[str, Any], zone, path: str) -> None:
    """The operating zone must contain the vehicle's start (sim.spawn)."""
    import numpy as np

    from quadrivio_navigation.guard import points_in_polygon

    spawn = (data.get("sim") or {}).get("spawn") or {}
    x, y = float(spawn.get("x", 0.0)), float(spawn.get("y", 0.0))
    if not points_in_polygon(np.array([[x, y]]), np.asarray(zone, dtype=float))[0]:
        raise ConfigError(f"{path}: guard.zone does not contain the start ({x:g}, {y:g}) (sim.spawn): the vehicle "
                          "would never move")


def _check_actors_clear_of_start(s: "Scenario", actors) -> None:
    """No actor may stand where the vehicle starts: their bodies would overlap at t = 0 and
    the physics push them apart (a person 0.5 m ahead of the spawn turned the vehicle 9 deg,
    counted a contact, and the run aborted). Checked with the actor as it stands at t = 0
    (its first waypoint and heading) against the body of the scenario's vehicle at sim.spawn."""
    import numpy as np

    from quadrivio_navigation.costmap import Footprint
    from quadrivio_navigation.fields import inside
    from quadrivio_navigation.guard import points_in_polygon
    from quadrivio_sim.actors import ActorMotion, footprint_polygon

    spawn = (s.data.get("sim") or {}).get("spawn") or {}
    x, y, yaw = (float(spawn.get(k, 0.0)) for k in ("x", "y", "yaw"))
    fp = Footprint.from_vehicle(vehicle(s))
    corners = fp.corners(x, y, yaw)
    for a in actors:
        pose = ActorMotion(a).pose(0.0)
        poly = np.array(footprint_polygon(a.geometry, a.dims, pose.x, pose.y, pose.yaw))
        # the outline densely (its edges), and its centre: any inside the vehicle's body, or
        # the body inside the actor (a large one), is an overlap
        edges = np.concatenate([np.linspace(p, q, 12, endpoint=False) for p, q in zip(poly, np.roll(poly, -1, 0))])
        pts = np.vstack([edges, [[pose.x, pose.y]]])
        if inside(fp, pts, x, y, yaw).any() or points_in_polygon(corners, poly).any():
            raise ConfigError(f"{s.path}: actor '{a.name}' stands where the vehicle starts: at ({pose.x:g}, "
                              f"{pose.y:g}) its body overlaps the vehicle's at sim.spawn ({x:g}, {y:g}); move its "
                              f"first waypoint")


def map_file(s: "Scenario") -> str:
    """The scenario's map file (resolved against the scenario's folder), '' without one."""
    from quadrivio_navigation.maps import resolve_map_file

    return resolve_map_file(str((s.data.get("map") or {}).get("file", "")), s.path)


def _check_map(data: Dict[str, Any], path: str) -> None:
    """The map loads, and a goal (path kind goal) lies on it."""
    from quadrivio_navigation.maps import load_map, resolve_map_file

    file = resolve_map_file(str((data.get("map") or {}).get("file", "")), path)
    kind = (data.get("path") or {}).get("kind")
    if not file:
        if kind == "goal":
            raise ConfigError(f"{path}: path kind 'goal' needs a map (map: file:)")
        return
    grid = load_map(file)  # MapError (a ConfigError) names the file and the problem
    if kind == "goal":
        goal = (data.get("path") or {}).get("goal", (0.0, 0.0, 0.0))
        if not grid.contains(goal[0], goal[1]):
            raise ConfigError(f"{path}: path.goal {list(goal)} is outside the map {file}")


def summary(s: Scenario) -> Tuple[str, ...]:
    return (f"scenario {s.name} ({os.path.relpath(s.path)}), seed {s.seed}", s.description)


def vehicle(s: Scenario, base=None):
    """The vehicle of scenario ``s``: ``base`` (default: vehicle.yaml's) with its ``vehicle:``
    section applied."""
    from quadrivio_description.vehicle import load_vehicle, with_overrides

    return with_overrides(base if base is not None else load_vehicle(), s.data.get("vehicle"), f"{s.path}: vehicle")
