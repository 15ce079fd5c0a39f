"""Trajectory follower: pure pursuit on the rear axle, speed from the path's profile.

For the rear axle centre at ``(x, y, theta)`` and the path point ``L_d`` ahead of the
nearest one (``L_d = clip(k v, L_min, L_max)``, shortened near the end), with ``alpha``
the angle from the heading to that point::

    kappa = 2 sin(alpha) / L_d,   delta = atan(L kappa),   handlebar = delta / ratio

clipped to the handlebar's limit. The speed setpoint is the profile's speed at the
nearest point (at least ``min_speed`` until the goal). The follower stops (status DONE)
within ``goal_tolerance`` of the end, and aborts (status ABORTED, full stop) when the
cross-track error exceeds ``max_cross_track`` or the pose is older than
``max_pose_age``: a stale pose must not steer the vehicle.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from quadrivio_description.config import param
from quadrivio_description.kinematics import delta_for_curvature
from quadrivio_description.vehicle import VehicleParams

from .paths import Path, SpeedProfileParams, Tracker

WAITING, FOLLOWING, DONE, ABORTED = 0, 1, 2, 3
STATUS_NAMES = {WAITING: "WAITING", FOLLOWING: "FOLLOWING", DONE: "DONE", ABORTED: "ABORTED"}


@dataclass(frozen=True)
class FollowerParams:
    lookahead_gain: float = param(0.8, lo=0.0, hi=10.0, unit="s", doc="lookahead distance per m/s")
    lookahead_min: float = param(1.8, lo=0.1, hi=50.0, unit="m", doc="shortest lookahead")
    lookahead_max: float = param(6.0, lo=0.1, hi=100.0, unit="m", doc="longest lookahead")
    min_speed: float = param(0.3, lo=0.0, hi=5.0, unit="m/s", doc="speed floor until the goal")
    goal_tolerance: float = param(0.5, lo=0.05, hi=10.0, unit="m", doc="done within this of the path's end")
    max_cross_track: float = param(4.0, lo=0.1, hi=100.0, unit="m", doc="abort beyond this cross-track error")
    max_pose_age: float = param(0.5, lo=0.01, hi=10.0, unit="s", doc="abort when the pose is older than this")
    stop_brake: float = param(0.6, lo=0.0, hi=1.0, doc="brake when done or aborted")
    search_window: float = param(6.0, lo=0.5, hi=100.0, unit="m", doc="progress search window along the path")

    def __post_init__(self) -> None:
        if self.lookahead_min > self.lookahead_max:
            raise ValueError("'lookahead_min' must not exceed 'lookahead_max'")


@dataclass(frozen=True)
class FollowerConfig:
    """The follower node's parameters (``config/follower.yaml``)."""
    rate: float = param(50.0, lo=1.0, hi=500.0, unit="Hz", doc="setpoint rate")
    profile: SpeedProfileParams = param(SpeedProfileParams())
    pure_pursuit: FollowerParams = param(FollowerParams())


@dataclass
class Command:
    speed: float  # [m/s]
    handlebar: float  # [rad]
    brake: float  # [1]
    status: int
    cross_track: float  # [m] signed, left positive
    progress: float  # [1] fraction of the path's length done
    remaining: float  # [m]
    reason: str = ""


class PurePursuit:
    def __init__(self, p: FollowerParams, path: Path, vehicle: VehicleParams) -> None:
        self.p, self.path, self.v = p, path, vehicle
        self.tracker = Tracker(path, p.search_window)
        self.status = FOLLOWING
        self.reason = ""
        self.max_handlebar = vehicle.steering.max_angle

    def stop(self, status: int, reason: str, xte: float = 0.0, progress: float = 0.0, remaining: float = 0.0) -> Command:
        self.status, self.reason = status, reason
        return Command(0.0, 0.0, self.p.stop_brake, status, xte, progress, remaining, reason)

    def update(self, x: float, y: float, theta: float, speed: float, pose_age: float = 0.0) -> Command:
        path = self.path
        if self.status in (DONE, ABORTED):
            return Command(0.0, 0.0, self.p.stop_brake, self.status, 0.0, 1.0 if self.status == DONE else 0.0, 0.0,
                           self.reason)
        if pose_age > self.p.max_pose_age:
            return self.stop(ABORTED, f"pose {pose_age:.2f} s old (> {self.p.max_pose_age} s)")
        i = self.tracker.nearest(x, y)
        xte = self.tracker.cross_track(x, y, i)
        remaining = path.length - float(path.s[i])
        progress = float(path.s[i]) / path.length
        if abs(xte) > self.p.max_cross_track:
            return self.stop(ABORTED, f"cross-track error {xte:.2f} m (> {self.p.max_cross_track} m)", xte, progress,
                             remaining)
        end_dist = math.hypot(path.x[-1] - x, path.y[-1] - y)
        if remaining < self.p.goal_tolerance + 1.0 and end_dist < self.p.goal_tolerance:
            return self.stop(DONE, "goal reached", xte, 1.0, 0.0)
        ld = min(self.p.lookahead_max, max(self.p.lookahead_min, self.p.lookahead_gain * abs(speed)))
        target_s = float(path.s[i]) + ld
        j = min(len(path) - 1, int(math.ceil(target_s / max(1e-9, path.s[1] - path.s[0]))))
        tx, ty = path.x[j], path.y[j]
        dist = max(1e-3, math.hypot(tx - x, ty - y))
        alpha = math.atan2(ty - y, tx - x) - theta
        kappa = 2.0 * math.sin(alpha) / dist
        h = delta_for_curvature(kappa, self.v.wheelbase) / self.v.steering.ratio
        h = max(-self.max_handlebar, min(self.max_handlebar, h))
        v_sp = max(self.p.min_speed, float(path.v[i])) if remaining > self.p.goal_tolerance else 0.0
        return Command(v_sp, h, 0.0, FOLLOWING, xte, progress, remaining)


def no_pose_command(p: FollowerParams) -> Command:
    return Command(0.0, 0.0, p.stop_brake, WAITING, 0.0, 0.0, math.nan, "no pose yet")

