"""Actors: people, animals and vehicles that no map holds, standing or moving on waypoints.

An actor is a rigid body the lasers and cameras see and the vehicle can hit. It stands at
its first waypoint until it starts, then walks the polyline of its waypoints at its speed
(heading along the leg), and

* ``once``: stops at the last waypoint;
* ``loop``: returns to the first waypoint and goes round again;
* ``back_and_forth``: turns back at either end.

It starts at sim time ``start_time``; with ``trigger_distance`` > 0 it waits instead until
the vehicle's ``base_link`` comes within that distance of it, then starts ``start_time``
seconds later (a person who steps out between two trees as the vehicle comes, or who
stands on the path for a while, then walks away). Actors move kinematically: a collision
does not push them (a person hit stands where they stand; the vehicle is pushed back).
They do not walk into the vehicle either: a step that would bring an actor closer than
``keep_clear`` to the vehicle's body, and closer than it was, is not taken; the actor waits
there, and walks on (its schedule later by the wait) once the step is clear. Without this, a
body moved kinematically into the vehicle shoved it aside with unbounded force: a worker
walking a lane's length shoved the standing vehicle round by 90 deg, 25 contacts, the
estimate and the lasers' view of the ground wrecked. What the vehicle drives into still
counts, waiting actor or not.

Shapes by ``kind`` unless ``size`` is given (length, width, height [m]; a cylinder's
diameter is its length): person a cylinder 0.6 x 0.6 x 1.8, animal a box 1.2 x 0.5 x 1.0
(a cow's body, legs included), vehicle a box 2.5 x 1.5 x 1.6, object a box 1 x 1 x 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

from quadrivio_config import ConfigError, from_mapping, param

DEFAULT_SIZE = {"person": (0.6, 0.6, 1.8), "animal": (1.2, 0.5, 1.0), "vehicle": (2.5, 1.5, 1.6),
                "object": (1.0, 1.0, 1.0)}
DEFAULT_SHAPE = {"person": "cylinder", "animal": "box", "vehicle": "box", "object": "box"}


@dataclass(frozen=True)
class ActorParams:
    name: str = param(doc="unique name (ground truth, contacts)")
    waypoints: Tuple[Tuple[float, float], ...] = param(unit="m", doc="[[x, y], ...] in the map frame; the first "
                                                                       "is where it stands before it starts")
    kind: str = param("person", choices=("person", "animal", "vehicle", "object"))
    speed: float = param(1.4, lo=0.0, hi=20.0, unit="m/s", doc="walking speed along the waypoints")
    mode: str = param("once", choices=("once", "loop", "back_and_forth"))
    start_time: float = param(0.0, lo=0.0, hi=1e6, unit="s",
                              doc="sim time it starts moving; with a trigger: the delay after it")
    trigger_distance: float = param(0.0, lo=0.0, hi=1000.0, unit="m",
                                    doc="start when the vehicle comes within this distance (0: no trigger)")
    shape: str = param("", choices=("", "cylinder", "box"), doc="empty: by kind")
    size: Tuple[float, ...] = param((), unit="m", doc="length, width, height; empty: by kind")
    yaw: float = param(math.nan, unit="rad", doc="heading while standing before it starts (NaN: along its first leg)")
    keep_clear: float = param(0.2, lo=0.0, hi=5.0, unit="m",
                              doc="it waits rather than step closer than this to the vehicle's body")

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("an actor needs a name")
        if len(self.waypoints) < 1:
            raise ValueError(f"actor '{self.name}': 'waypoints' needs at least one [x, y]")
        for w in self.waypoints:
            if len(w) != 2 or not all(math.isfinite(v) for v in w):
                raise ValueError(f"actor '{self.name}': waypoint {list(w)} is not a finite [x, y]")
        if self.size and (len(self.size) != 3 or not all(0.01 <= s <= 50.0 for s in self.size)):
            raise ValueError(f"actor '{self.name}': 'size' must be [length, width, height] in 0.01-50 m")
        if self.mode != "once" and len(self.waypoints) < 2:
            raise ValueError(f"actor '{self.name}': mode '{self.mode}' needs at least two waypoints")
        if self.mode == "loop" and len(self.waypoints) == 2:
            raise ValueError(f"actor '{self.name}': a loop needs three waypoints or more (use back_and_forth)")

    @property
    def dims(self) -> Tuple[float, float, float]:
        return tuple(self.size) if self.size else DEFAULT_SIZE[self.kind]  # type: ignore[return-value]

    @property
    def geometry(self) -> str:
        return self.shape or DEFAULT_SHAPE[self.kind]


def load_actors(data, source: str) -> Tuple[ActorParams, ...]:
    """Actors from a scenario's ``actors:`` list (ConfigError naming the source and actor)."""
    if data is None:
        return ()
    if not isinstance(data, (list, tuple)):
        raise ConfigError(f"{source}: 'actors' must be a list of actors")
    out: List[ActorParams] = []
    for i, item in enumerate(data):
        if not isinstance(item, dict):
            raise ConfigError(f"{source}: actors[{i}] must be a mapping (name, kind, waypoints, ...)")
        try:
            out.append(from_mapping(ActorParams, item, source, f"actors[{i}]"))
        except ValueError as exc:
            raise ConfigError(f"{source}: actors[{i}]: {exc}") from exc
    names = [a.name for a in out]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"{source}: actor names must be unique: {', '.join(dup)}")
    return tuple(out)


@dataclass(frozen=True)
class ActorPose:
    x: float
    y: float
    yaw: float
    speed: float  # [m/s]


class ActorMotion:
    """Where an actor is at sim time ``t`` (:meth:`update` must see every time in order)."""

    def __init__(self, p: ActorParams) -> None:
        self.p = p
        pts = list(p.waypoints)
        if p.mode == "loop":
            pts = pts + [pts[0]]
        elif p.mode == "back_and_forth":
            pts = pts + pts[-2::-1]
        self.pts = pts
        self.lengths = [math.hypot(b[0] - a[0], b[1] - a[1]) for a, b in zip(pts, pts[1:])]
        self.total = sum(self.lengths)
        self.start: Optional[float] = None if p.trigger_distance > 0.0 else p.start_time
        self.triggered_at: Optional[float] = None
        self.last: Optional[ActorPose] = None  # the pose of the last update
        self.t_last: Optional[float] = None  # the time of the last update
        self.previous: Optional[ActorPose] = None  # the pose and time of the update before
        self.t_previous: Optional[float] = None
        self.held = 0.0  # [s] time spent waiting for the vehicle: the walk is that much later
        self.waiting = False  # the last update's step was held back

    def update(self, t: float, vehicle_xy: Tuple[float, float]) -> ActorPose:
        p = self.p
        if self.start is None:
            x0, y0 = self.pts[0]
            if math.hypot(vehicle_xy[0] - x0, vehicle_xy[1] - y0) <= p.trigger_distance:
                self.triggered_at = t
                self.start = t + p.start_time
        self.previous, self.t_previous = self.last, self.t_last
        self.last, self.t_last = self.pose(t), t
        self.waiting = False
        return self.last

    def hold_back(self) -> ActorPose:
        """Undo the last :meth:`update`'s step: the actor stays where it was, and its walk
        from there is later by the time since the update before (its pose at ``t_last`` is
        the previous one); returns that pose."""
        if self.previous is None or self.t_previous is None:
            return self.last
        self.held += self.t_last - self.t_previous
        self.last = ActorPose(self.previous.x, self.previous.y, self.previous.yaw, 0.0)
        self.waiting = True
        return self.last

    def pose(self, t: float) -> ActorPose:
        """Where it is at ``t`` (at or after the last update's time: waits so far included)."""
        p = self.p
        moving = self.start is not None and t - self.held >= self.start and p.speed > 0.0 and self.total > 0.0
        s = (t - self.held - self.start) * p.speed if moving else 0.0
        if p.mode == "once" and s >= self.total:
            s, moving = self.total, False
        elif p.mode != "once" and self.total > 0.0:
            s = math.fmod(s, self.total)
        return self._at(s, moving)

    def _at(self, s: float, moving: bool) -> ActorPose:
        for (a, b), length in zip(zip(self.pts, self.pts[1:]), self.lengths):
            if s <= length or length == 0.0 and s <= 0.0:
                u = s / length if length > 0.0 else 0.0
                yaw = math.atan2(b[1] - a[1], b[0] - a[0])
                if not moving and s <= 0.0 and math.isfinite(self.p.yaw):
                    yaw = self.p.yaw
                return ActorPose(a[0] + u * (b[0] - a[0]), a[1] + u * (b[1] - a[1]), yaw,
                                 self.p.speed if moving else 0.0)
            s -= length
        last, before = self.pts[-1], self.pts[-2] if len(self.pts) > 1 else self.pts[-1]
        yaw = math.atan2(last[1] - before[1], last[0] - before[0]) if len(self.pts) > 1 else \
            (self.p.yaw if math.isfinite(self.p.yaw) else 0.0)
        return ActorPose(last[0], last[1], yaw, 0.0)


def footprint_polygon(kind: str, dims: Sequence[float], x: float, y: float, yaw: float) -> List[Tuple[float, float]]:
    """The body's outline in the map frame (a cylinder as a 16-gon around it)."""
    if kind == "cylinder":
        r = 0.5 * dims[0]
        return [(x + r * math.cos(2 * math.pi * k / 16), y + r * math.sin(2 * math.pi * k / 16)) for k in range(16)]
    c, s = math.cos(yaw), math.sin(yaw)
    hx, hy = 0.5 * dims[0], 0.5 * dims[1]
    return [(x + c * dx - s * dy, y + s * dx + c * dy) for dx, dy in ((hx, hy), (-hx, hy), (-hx, -hy), (hx, -hy))]
