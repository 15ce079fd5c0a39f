"""Trajectory follower: pure pursuit on the rear axle, forwards and in reverse, with cusps.

A route is a list of segments, each driven in one direction (+1 forward, -1 reverse): a
planned path is split where its driving direction changes (a cusp). On a segment, with
the rear axle centre at ``(x, y, theta)``, the motion heading ``psi = theta`` forward and
``theta + pi`` in reverse, the path point ``L_d`` ahead of the nearest one
(``L_d = clip(k |v|, L_min, L_max)``; beyond the segment's end, on the straight line
continuing its last heading) and ``alpha`` the angle from ``psi`` to that point::

    kappa = 2 sin(alpha) / L_d               (curvature of the motion, left positive)
    delta = atan(L kappa)  forward,   delta = -atan(L kappa)  in reverse
    handlebar = delta / ratio

(the rear axle moves on curvature ``tan(delta) / L`` about its motion heading forwards,
and ``-tan(delta) / L`` backwards), clipped to the handlebar's limit. The speed setpoint
is the segment's profile at the nearest point (at least ``min_speed``, at most
``reverse_speed`` backwards), signed by the direction, and 0 within ``stop_distance`` of
the segment's end: the profile brings the vehicle to rest at every cusp and at the goal.

At a cusp, once stopped (``|v| < stop_speed``) at the segment's end (reached along the path,
whatever the sideways offset: the next segment's pure pursuit takes it up), the next
segment starts; so it does when the vehicle stands held short of the cusp (by the
obstacle guard) within ``cusp_tolerance`` of it. From rest (a cusp, a route's start) the
handlebar turns first: the speed setpoint stays 0 until the handlebar's is within
``steer_first`` of what the pursuit asks (a replan's path reversed 0.16 m, then went forward
on an arc at the planning radius; driven off at once while the handlebar swung from -0.38 to
+0.42 rad, the vehicle ran wide, and at full lock it had no authority left to come back:
1.0 m off the path). At the route's end, once stopped, the follower is DONE when it is within
``goal_tolerance`` and ``heading_tolerance`` (15 deg) of the goal pose, DONE with a parking
error (said in the reason, ``parking_error``) within twice those, and ABORTED (missed the
goal, with the errors) beyond. A stale pose must not steer the vehicle: one older than
``pose_budget`` over the speed (within [``min_pose_age``, ``max_pose_age``]: 0.08 s at
3 m/s) stops it with the brake, still FOLLOWING, until a fresh pose comes, and it drives
on from rest. It aborts at once (full stop) when the cross-track error exceeds
``max_cross_track``, and when, told to move, it has got less than ``stall_distance``
further along the route in ``stall_time`` (blocked by something the map does not show,
stuck; short of the route's first pose, the way to it counts). :meth:`PurePursuit.stop`
ends a route with a controlled stop.

Setpoints change no faster than the vehicle can follow when ``update`` gets the time: the
speed by the profile's acceleration and deceleration limits, the handlebar by the
steering servo's rate, so a new route while driving (a replan) gives no jump; an abort
brakes at once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import param
from quadrivio_description.kinematics import delta_for_curvature
from quadrivio_description.vehicle import VehicleParams

from .paths import Path, SpeedProfileParams, Tracker, make_path

WAITING, FOLLOWING, DONE, ABORTED = 0, 1, 2, 3
STATUS_NAMES = {WAITING: "WAITING", FOLLOWING: "FOLLOWING", DONE: "DONE", ABORTED: "ABORTED"}


@dataclass(frozen=True)
class FollowerParams:
    lookahead_gain: float = param(0.8, lo=0.0, hi=10.0, unit="s", doc="lookahead distance per m/s")
    lookahead_min: float = param(1.8, lo=0.1, hi=50.0, unit="m", doc="shortest lookahead")
    lookahead_max: float = param(6.0, lo=0.1, hi=100.0, unit="m", doc="longest lookahead")
    min_speed: float = param(0.3, lo=0.0, hi=5.0, unit="m/s", doc="speed floor until a segment's end")
    reverse_speed: float = param(1.0, lo=0.1, hi=10.0, unit="m/s", doc="speed limit in reverse")
    goal_tolerance: float = param(0.5, lo=0.05, hi=10.0, unit="m", doc="done within this of the path's end")
    heading_tolerance: float = param(0.2618, lo=0.01, hi=3.2, unit="rad",
                                     doc="... and within this of its heading (15 deg); within twice the tolerances "
                                         "it is DONE with a parking error, beyond them ABORTED")
    stop_distance: float = param(0.1, lo=0.0, hi=5.0, unit="m", doc="speed setpoint 0 this far from a segment's end")
    stop_speed: float = param(0.1, lo=0.01, hi=2.0, unit="m/s", doc="the vehicle counts as stopped below this")
    cusp_tolerance: float = param(0.6, lo=0.05, hi=10.0, unit="m",
                                  doc="held short of a cusp (by the guard), change direction within this of it")
    steer_first: float = param(0.1, lo=0.0, hi=1.0, unit="rad",
                               doc="from rest (a cusp, a route's start), the handlebar setpoint comes within this "
                                   "of the pursuit's before the speed setpoint leaves 0 (0: drive off at once)")
    max_cross_track: float = param(4.0, lo=0.1, hi=100.0, unit="m", doc="abort beyond this cross-track error")
    pose_budget: float = param(0.25, lo=0.01, hi=10.0, unit="m",
                               doc="how far the vehicle may drive on the last pose before it is stale: the pose's "
                                   "age limit is this over the speed (a safety budget, see max_pose_age)")
    min_pose_age: float = param(0.08, lo=0.01, hi=10.0, unit="s",
                                doc="the age limit is never below this (4 periods of the 50 Hz predictor)")
    max_pose_age: float = param(0.5, lo=0.01, hi=10.0, unit="s",
                                doc="nor above this (standing, slow): a pose older than the limit stops the vehicle "
                                    "until a fresh one comes, then it drives on")
    stall_time: float = param(10.0, lo=0.5, hi=600.0, unit="s",
                              doc="abort when the vehicle, told to move, gets less than stall_distance further "
                                  "along the path in this long (blocked, stuck)")
    stall_distance: float = param(0.3, lo=0.01, hi=10.0, unit="m", doc="see stall_time")
    stop_brake: float = param(0.6, lo=0.0, hi=1.0, doc="brake when done or aborted")
    setpoint_decel: float = param(2.0, lo=0.05, hi=10.0, unit="m/s^2",
                                  doc="how fast the speed setpoint may fall, at least the profile's decel: a "
                                      "vehicle lags its setpoint, so the profile at its position falls faster than "
                                      "the profile's own rate, and a setpoint held to that rate overshot the goal")
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
    speed: float  # [m/s] signed: negative in reverse
    handlebar: float  # [rad]
    brake: float  # [1]
    status: int
    cross_track: float  # [m] signed, left of the motion positive
    progress: float  # [1] fraction of the route's length done
    remaining: float  # [m] route length still to go
    reason: str = ""
    segment: int = 0
    direction: int = 1


@dataclass
class Segment:
    path: Path  # x, y, theta = heading of the motion
    direction: int  # +1 forward, -1 reverse


class Route:
    """Segments of one driving direction each, and the goal pose (the vehicle's heading)."""

    def __init__(self, segments: List[Segment], goal_heading: float) -> None:
        if not segments:
            raise ValueError("a route needs at least one segment")
        self.segments = segments
        self.goal_heading = goal_heading
        self.lengths = [seg.path.length for seg in segments]
        self.length = float(sum(self.lengths))

    @property
    def goal(self):
        p = self.segments[-1].path
        return float(p.x[-1]), float(p.y[-1]), self.goal_heading


def directions(poses: np.ndarray) -> np.ndarray:
    """Driving direction (+1/-1) of each step between poses (x, y, vehicle heading): forward
    when the step points along the heading. Steps too short to tell take the previous one's."""
    d = np.diff(poses[:, :2], axis=0)
    dot = d[:, 0] * np.cos(poses[:-1, 2]) + d[:, 1] * np.sin(poses[:-1, 2])
    out = np.where(dot < 0.0, -1, 1).astype(int)
    tiny = np.hypot(d[:, 0], d[:, 1]) < 1e-6
    for i in np.flatnonzero(tiny):
        out[i] = out[i - 1] if i > 0 else 1
    return out


def make_route(poses: Sequence[Sequence[float]], profile: SpeedProfileParams, reverse_speed: float = 1.0,
               v_start: float = 0.0, ds: float = 0.1) -> Route:
    """A route through ``poses`` (x, y, vehicle heading), split at every change of driving
    direction; ``v_start`` [m/s, signed] is the vehicle's speed when it takes the route."""
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] < 3 or len(poses) < 2:
        raise ValueError("a route needs at least 2 poses (x, y, heading)")
    if not np.all(np.isfinite(poses[:, :3])):
        raise ValueError("a route's poses must be finite")
    dirs = directions(poses)
    segments: List[Segment] = []
    start = 0
    for i in range(1, len(dirs) + 1):
        if i == len(dirs) or dirs[i] != dirs[start]:
            pts = poses[start:i + 1, :2]
            d = int(dirs[start])
            if np.sum(np.hypot(np.diff(pts[:, 0]), np.diff(pts[:, 1]))) > 1e-3:
                v0 = abs(v_start) if not segments and v_start * d > 0 else 0.0
                path = make_path(pts, profile, ds, v_start=v0, v_max=None if d > 0 else reverse_speed)
                segments.append(Segment(path, d))
            start = i
    if not segments:
        raise ValueError("a route needs poses that move")
    return Route(segments, float(poses[-1, 2]))


def _wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


class PurePursuit:
    def __init__(self, p: FollowerParams, route, vehicle: VehicleParams, last_speed: float = 0.0,
                 last_handlebar: float = 0.0, last_time: Optional[float] = None) -> None:
        """``route``: a :class:`Route` or a forward :class:`Path`; ``last_speed``,
        ``last_handlebar`` and ``last_time``: the setpoints sent before and when (a replan
        continues from them)."""
        if isinstance(route, Path):
            route = Route([Segment(route, 1)], float(route.theta[-1]))
        self.p, self.route, self.v = p, route, vehicle
        self.k = 0
        self.tracker = Tracker(route.segments[0].path, p.search_window)
        self.status = FOLLOWING
        self.reason = ""
        self.max_handlebar = vehicle.steering.max_angle
        self.rate = vehicle.steering.max_rate
        self.stopping = False
        self.t_last: Optional[float] = last_time
        self.sp_speed, self.sp_handlebar = last_speed, last_handlebar
        self.accel = self.decel = self.stop_decel = math.inf
        self.stall_ref: Optional[Tuple[float, float]] = None  # (time, route progress [m]) of the last progress
        self.waiting_pose = ""  # why the vehicle stands waiting for a fresh pose ("": it does not)
        self.parking_error = False  # DONE, but parked outside the tolerance (within twice it)

    @property
    def path(self) -> Path:
        return self.route.segments[self.k].path

    def set_limits(self, accel: float, decel: float) -> None:
        """Speed setpoint slew limits [m/s^2]: the speed profile's; when slowing down along
        the profile at least ``setpoint_decel`` (see FollowerParams), in a controlled stop
        the profile's own."""
        self.accel, self.decel, self.stop_decel = accel, max(decel, self.p.setpoint_decel), decel

    # ------------------------------------------------------------------ ending
    def abort(self, reason: str, xte: float = 0.0) -> Command:
        """Stop at once with the brake (a stale pose, off the path)."""
        self.status, self.reason = ABORTED, reason
        self.sp_speed = self.sp_handlebar = 0.0
        return Command(0.0, 0.0, self.p.stop_brake, ABORTED, xte, self._progress(), self._remaining(), reason, self.k,
                       self.route.segments[self.k].direction)

    def stop(self, reason: str) -> None:
        """End the route with a controlled stop: decelerate along the path, then ABORTED."""
        if self.status == FOLLOWING:
            self.stopping, self.reason = True, reason

    def _done_command(self) -> Command:
        return Command(0.0, self.sp_handlebar if self.status == DONE else 0.0, self.p.stop_brake, self.status, 0.0,
                       1.0 if self.status == DONE else self._progress(), 0.0 if self.status == DONE else
                       self._remaining(), self.reason, self.k, self.route.segments[self.k].direction)

    def _progress(self) -> float:
        done = sum(self.route.lengths[:self.k]) + float(self.path.s[self.tracker.i])
        return done / max(self.route.length, 1e-9)

    def _remaining(self) -> float:
        return self.route.length - sum(self.route.lengths[:self.k]) - float(self.path.s[self.tracker.i])

    # ------------------------------------------------------------------ update
    def update(self, x: float, y: float, theta: float, speed: float, pose_age: float = 0.0,
               t: Optional[float] = None, held: bool = False) -> Command:
        """One cycle from the pose (x, y, heading), the speed [m/s, signed], the pose's age
        [s] and, for slew-limited setpoints, the time [s]. ``held``: something downstream
        (the obstacle guard) holds the vehicle below the speed asked for, so not getting
        along the path is no stall."""
        if self.status in (DONE, ABORTED):
            return self._done_command()
        v_ref = max(abs(speed), abs(self.sp_speed))
        limit = self.pose_age_limit(v_ref)
        if pose_age > limit:
            return self._wait_for_pose(pose_age, limit, v_ref, t)
        self.waiting_pose = ""
        seg = self.route.segments[self.k]
        path, d = seg.path, seg.direction
        i = self.tracker.nearest(x, y)
        xte = self.tracker.cross_track(x, y, i)
        if abs(xte) > self.p.max_cross_track:
            return self.abort(f"cross-track error {xte:.2f} m (> {self.p.max_cross_track} m)", xte)
        seg_left = path.length - float(path.s[i])
        end_x, end_y = float(path.x[-1]), float(path.y[-1])
        end_dist = math.hypot(end_x - x, end_y - y)
        # how far from the segment's end along its last heading (negative: passed it)
        along_end = (end_x - x) * math.cos(path.theta[-1]) + (end_y - y) * math.sin(path.theta[-1])
        stopped = abs(speed) < self.p.stop_speed
        last = self.k == len(self.route.segments) - 1
        # at the end: by arc length, or (close to it) by having reached the line through it
        at_end = seg_left <= self.p.stop_distance or (seg_left < self.p.lookahead_min and
                                                      along_end <= self.p.stop_distance)
        # At a cusp: stopped at the segment's end (along the path; a sideways offset is the next
        # segment's to take up: stopped 0.7 m beside a cusp, the vehicle stood there for good),
        # or held short of it by the obstacle guard within cusp_tolerance (the obstacle a replan
        # turns back from stands beyond it): the vehicle changes direction where it stands
        if stopped and (at_end or held):
            if not last and not self.stopping and (at_end or end_dist <= self.p.cusp_tolerance):
                self.k += 1  # the cusp: take the next segment, from rest
                self.tracker = Tracker(self.route.segments[self.k].path, self.p.search_window)
                self.sp_speed = 0.0
                return self.update(x, y, theta, speed, pose_age, t, held)
            if (last or self.stopping) and at_end:
                return self._finish(x, y, theta)
        if self.stopping and stopped:
            self.status = ABORTED
            return self._done_command()
        # pure pursuit on the motion heading
        psi = theta if d > 0 else theta + math.pi
        ld = min(self.p.lookahead_max, max(self.p.lookahead_min, self.p.lookahead_gain * abs(speed)))
        target_s = float(path.s[i]) + ld
        if target_s <= path.length:
            j = int(np.searchsorted(path.s, target_s))
            tx, ty = float(path.x[j]), float(path.y[j])
        else:  # beyond the end: on the line that continues the segment's last heading
            extra = target_s - path.length
            tx = end_x + extra * math.cos(path.theta[-1])
            ty = end_y + extra * math.sin(path.theta[-1])
        dist = max(1e-3, math.hypot(tx - x, ty - y))
        alpha = math.atan2(ty - y, tx - x) - psi
        kappa = 2.0 * math.sin(alpha) / dist
        delta = delta_for_curvature(kappa, self.v.wheelbase)
        h = (delta if d > 0 else -delta) / self.v.steering.ratio
        h = max(-self.max_handlebar, min(self.max_handlebar, h))
        if self.stopping or at_end:
            v_sp = 0.0
        else:
            v_sp = max(self.p.min_speed, float(path.v[i]))
            if d < 0:
                v_sp = min(v_sp, self.p.reverse_speed)
        v_sp *= d
        if self.p.steer_first > 0.0 and stopped and self.sp_speed == 0.0 and \
                abs(h - self.sp_handlebar) > self.p.steer_first:
            v_sp = 0.0  # from rest, turn the handlebar first: off at once, an arc at full lock is lost
        v_sp, h = self._slew(v_sp, h, t)
        if t is not None:
            stalled = self._stalled(t, 0.0 if held else v_sp, x, y)
            if stalled:
                return self.abort(stalled, xte)
        return Command(v_sp, h, 0.0, FOLLOWING, xte, self._progress(), self._remaining(),
                       self.reason if self.stopping else "", self.k, d)

    def pose_age_limit(self, speed: float) -> float:
        """How old the pose may be at ``speed`` [m/s]: the vehicle drives at most
        ``pose_budget`` on it, within [min_pose_age, max_pose_age]."""
        if speed <= 1e-6:
            return self.p.max_pose_age
        return max(self.p.min_pose_age, min(self.p.max_pose_age, self.p.pose_budget / speed))

    def _wait_for_pose(self, age: float, limit: float, speed: float, t: Optional[float]) -> Command:
        """A stale pose (a dead or stalled localization): brake and wait on the route; once a
        fresh pose comes, drive on from rest (the speed setpoint ramps up from 0 again)."""
        self.waiting_pose = (f"waiting for a fresh pose: {age:.2f} s old (> {limit:.2f} s: {self.p.pose_budget} m "
                             f"at {speed:.1f} m/s)")
        self.sp_speed = 0.0
        if t is not None:
            self.t_last = t  # the speed setpoint ramps up from 0 from now
        self.stall_ref = None  # standing for the pose is no stall
        seg = self.route.segments[self.k]
        return Command(0.0, self.sp_handlebar, self.p.stop_brake, FOLLOWING, 0.0, self._progress(),
                       self._remaining(), self.waiting_pose, self.k, seg.direction)

    def _stalled(self, t: float, v_sp: float, x: float, y: float) -> str:
        """A reason to abort when the vehicle, told to move, does not get along the route.
        Short of the route's first pose (a reference path starts 1 m ahead of the vehicle)
        the way there counts: the route as if it began where the vehicle is. Counted from
        the first pose only, a vehicle slow to start up an 18 % slope (5 s to move, then
        0.3 m/s) was aborted for "0.20 m along the path in 10 s" after driving 1.2 m."""
        done = self.route.length - self._remaining()
        if self.k == 0 and self.tracker.i == 0 and len(self.path) > 1:
            p = self.path
            tx, ty = math.cos(p.theta[0]), math.sin(p.theta[0])
            done -= max(0.0, -((x - p.x[0]) * tx + (y - p.y[0]) * ty))  # how far short of it, along its heading
        if abs(v_sp) < 0.5 * self.p.min_speed or self.stall_ref is None or \
                abs(done - self.stall_ref[1]) >= self.p.stall_distance:
            self.stall_ref = (t, done)
            return ""
        if t - self.stall_ref[0] > self.p.stall_time:
            return (f"no progress: {abs(done - self.stall_ref[1]):.2f} m along the path in "
                    f"{t - self.stall_ref[0]:.0f} s while driving (blocked?)")
        return ""

    def _finish(self, x: float, y: float, theta: float) -> Command:
        gx, gy, gth = self.route.goal
        e = math.hypot(gx - x, gy - y)
        eh = abs(_wrap(gth - theta))
        if self.stopping:
            self.status = ABORTED
        elif e <= self.p.goal_tolerance and eh <= self.p.heading_tolerance:
            self.status, self.reason = DONE, f"goal reached: {e:.2f} m, {math.degrees(eh):.1f} deg off"
        elif e <= 2.0 * self.p.goal_tolerance and eh <= 2.0 * self.p.heading_tolerance:
            # Arrived, and parked a little off: a parking error, not an abort of a run that arrived
            self.status, self.parking_error = DONE, True
            self.reason = (f"arrived with a parking error: {e:.2f} m and {math.degrees(eh):.1f} deg from the goal "
                           f"(tolerance {self.p.goal_tolerance} m, {math.degrees(self.p.heading_tolerance):.1f} deg)")
        else:
            self.status = ABORTED
            self.reason = (f"stopped {e:.2f} m and {math.degrees(eh):.1f} deg from the goal (tolerance "
                           f"{self.p.goal_tolerance} m, {math.degrees(self.p.heading_tolerance):.1f} deg)")
        return self._done_command()

    def _slew(self, v_sp: float, h: float, t: Optional[float]):
        if t is None or self.t_last is None:
            self.t_last = t
            self.sp_speed, self.sp_handlebar = v_sp, h
            return v_sp, h
        dt = max(0.0, t - self.t_last)
        self.t_last = t
        prev = self.sp_speed
        speeding_up = abs(v_sp) > abs(prev) and v_sp * prev >= 0.0
        limit = (self.accel if speeding_up else self.stop_decel if self.stopping else self.decel) * dt
        v = prev + max(-limit, min(limit, v_sp - prev))
        dh = self.rate * dt
        hh = self.sp_handlebar + max(-dh, min(dh, h - self.sp_handlebar))
        self.sp_speed, self.sp_handlebar = v, hh
        return v, hh


def no_pose_command(p: FollowerParams) -> Command:
    return Command(0.0, 0.0, p.stop_brake, WAITING, 0.0, 0.0, math.nan, "no pose yet")
