"""The obstacle guard: a protective stop on the setpoint path that nothing upstream can bypass.

The follower (or the excitation program) *requests* setpoints; the guard passes each one
on to the PLCClient, limited by what the lasers see, the operating zone and its own
inputs' health. Fields are computed from the motion, not drawn
(:mod:`quadrivio_navigation.fields`): with ``d_free`` the distance the footprint can
drive along its path before it touches a laser point,

* **protective field** ``d_prot = d_stop(v, brake) + margin`` at the measured speed ``v``:
  ``d_free < d_prot`` while moving is a protective stop (STOP: speed 0, full brake);
* **warning field**: the speed is limited to ``v_allow(d_free - warning_margin)`` at the
  gentle deceleration, with the next scan's period in the reaction time, so that a
  vehicle slowing down as told never enters its protective field at speed (SLOW); closer
  than ``warning_margin`` it may still creep at ``creep_speed`` down to ``creep_margin``
  (at creep speed the protective field is shorter than that: tight turns past trees);
* after a stop (STOP or FAULT) the vehicle is held (HOLD) until the protective field of
  the requested speed has been clear for ``clear_time``, then the speed limit is released
  at ``release_accel``.

The laser facing the motion (forward: the scanners that cover ``forward``; reverse:
``reverse``) must be fresh: a scanner silent for ``scan_timeout``, blinded (more than
``blind_fraction`` of its rays invalid), or without a transform, a silent vehicle state
or, with an operating zone, a silent or too uncertain pose, is a FAULT: speed 0, brake,
with the reason.

**Operating zone** (ISO 18497-3's "autonomous operating zone"): a simple polygon in the
map frame. The footprint, grown by ``zone_sigmas`` times the pose's horizontal standard
deviation, swept over the protective distance from the predicted pose, must stay inside
it; otherwise the vehicle stops (field "zone"). So does a position standard deviation
above ``max_position_sd``: the estimate cannot tell where the edge is.

**Slope.** The braking deceleration is cut by the downhill grade the vehicle brakes on:
the mean grade over the stopping distance, not the body's momentary pitch (on a bump's face
the body pitches 8-14 deg over 12 cm bumps, and taken as the grade that stretched the
protective field at 3 m/s from 2.3 to 5-6 m, where the scan plane meets the ground). With
a DEM (``heights``) and a fresh pose it is the DEM's grade from the vehicle to the end of
the stopping distance along its heading, ``atan((h(0) - h(d)) / d)``, worked out twice
(the distance at the level grade, then at that grade: the energy the brake must take out
over that stretch); without, the pitch low-passed over ``slope_smoothing``.

The core is ROS-free: :class:`Guard` takes plain numbers and returns a :class:`Decision`
and the setpoint to send.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from typing import Dict, Optional, Sequence, Tuple

import numpy as np

from quadrivio_config import ConfigError, load_yaml, param
from quadrivio_description.vehicle import VehicleParams

from .costmap import Footprint
from .tracks import MotionTracker, TrackParams
from .fields import (NO_RETURN, ScanPoints, allowed_speed, blinded_reason, effective_decel, free_distance, inside,
                     stopping_distance, sweep)

CLEAR, SLOW, STOP, HOLD, FAULT = 0, 1, 2, 3, 4
ACTION_NAMES = {CLEAR: "CLEAR", SLOW: "SLOW", STOP: "STOP", HOLD: "HOLD", FAULT: "FAULT"}
FAULT_RELOG = 5.0  # [s] a FAULT that lasts is logged again this often while its reason is not the one logged


class DecisionLog:
    """Which decisions the guard logs: a change of action, but not between CLEAR and SLOW nor
    into the first; and a FAULT that lasts, again every ``FAULT_RELOG`` s while its reason is
    not the one logged (a laser that comes back blinded: still stopped, for another reason; a
    FAULT from the start, once it has lasted ``FAULT_RELOG``). guard_core.h's DecisionLog."""

    def __init__(self) -> None:
        self.reason = ""
        self.t: Optional[float] = None

    def worth(self, now: float, action: int, before: Optional[int], reason: str) -> bool:
        if self.t is None:
            self.t = now
        if before is None:
            return False
        if action != before:
            ok = {action, before} != {CLEAR, SLOW}
        else:
            ok = action == FAULT and reason != self.reason and now - self.t >= FAULT_RELOG
        if ok:
            self.reason, self.t = reason, now
        return ok


@dataclass(frozen=True)
class ScannerParams:
    topic: str = param(doc="the LaserScan topic (relative)")
    frame: str = param(doc="the frame_id its scans must carry")
    covers: str = param("forward", choices=("forward", "reverse", "both"),
                        doc="the direction of motion this scanner guards (its field of view)")
    no_return: str = param("inf", choices=NO_RETURN,
                           doc="how its driver reports a ray that saw nothing: inf (REP 117), zero (0.0: LMS1xx, "
                               "older sick_tim, Ouster) or beyond_max (a range beyond range_max: "
                               "pointcloud_to_laserscan without use_inf)")


@dataclass(frozen=True)
class GuardParams:
    scanners: Tuple[ScannerParams, ...] = param(
        (ScannerParams("scan/front", "laser_front", "forward"), ScannerParams("scan/rear", "laser_rear", "reverse")),
        doc="the laser scanners")
    padding: float = param(0.15, lo=0.0, hi=2.0, unit="m",
                           doc="the footprint grown on every side (tracking error, the body's shape)")
    step: float = param(0.05, lo=0.01, hi=0.5, unit="m", doc="sweep step along the path")
    brake_decel: float = param(3.5, lo=0.2, hi=15.0, unit="m/s^2",
                               doc="deceleration of a full-brake stop on level ground (measured in the simulator: "
                                   "4.2-4.4 from 2-3 m/s; lower for wet grass)")
    slow_decel: float = param(1.0, lo=0.1, hi=15.0, unit="m/s^2",
                              doc="deceleration the warning field plans with (below the speed loop's ramp)")
    brake_latency: float = param(0.15, lo=0.0, hi=2.0, unit="s",
                                 doc="from the guard's decision to the brakes acting: link, PLC cycle, brake servo "
                                     "dead time and rise (the scan's own age is added per scan)")
    margin: float = param(0.3, lo=0.0, hi=5.0, unit="m", doc="protective field beyond the stopping distance")
    warning_margin: float = param(0.8, lo=0.0, hi=10.0, unit="m",
                                  doc="where the warning field's slowdown brings the vehicle to creep speed")
    creep_speed: float = param(0.3, lo=0.0, hi=2.0, unit="m/s",
                               doc="the speed still allowed closer than warning_margin, down to creep_margin (tight "
                                   "turns past trees; 0: none)")
    creep_margin: float = param(0.45, lo=0.0, hi=10.0, unit="m",
                                doc="closer than this along the path the vehicle stands (at creep speed it is beyond "
                                    "the protective field)")
    scan_period: float = param(0.1, lo=0.005, hi=2.0, unit="s",
                               doc="the scanners' period (the warning field allows for a scan this late)")
    scan_timeout: float = param(0.35, lo=0.01, hi=10.0, unit="s",
                                doc="a scanner silent for this long (by the stamp of its last scan) stops the vehicle")
    max_scan_age: float = param(0.25, lo=0.01, hi=10.0, unit="s", doc="a scan older than this on arrival is stale")
    max_future: float = param(0.05, lo=0.0, hi=10.0, unit="s", doc="a stamp further ahead of the clock is refused")
    state_timeout: float = param(0.2, lo=0.01, hi=10.0, unit="s",
                                 doc="the vehicle state (measured speed) silent for this long stops the vehicle")
    blind_fraction: float = param(0.5, lo=0.0, hi=1.0,
                                  doc="more than this fraction of a scan's rays invalid (NaN, or finite outside "
                                      "[range_min, range_max]): blinded, stop")
    clear_time: float = param(1.0, lo=0.0, hi=60.0, unit="s", doc="after a stop, the field must stay clear this long")
    release_accel: float = param(0.5, lo=0.05, hi=10.0, unit="m/s^2", doc="how fast the limit rises after a hold")
    stop_speed: float = param(0.1, lo=0.01, hi=2.0, unit="m/s", doc="the vehicle counts as stopped below this")
    stop_brake: float = param(1.0, lo=0.0, hi=1.0, doc="brake demand of a stop")
    slope_unknown: float = param(0.15, lo=0.0, hi=1.0, unit="rad",
                                 doc="downhill slope assumed while the IMU is silent")
    slope_tau: float = param(4.0, lo=0.01, hi=30.0, unit="s",
                             doc="time constant of the attitude filter's pull toward the accelerometer")
    imu_timeout: float = param(0.5, lo=0.01, hi=10.0, unit="s", doc="after this the slope is slope_unknown")
    slope_smoothing: float = param(1.0, lo=0.0, hi=30.0, unit="s",
                                   doc="without a DEM the braking slope is the pitch low-passed this long: a "
                                       "bump's face is not the grade the vehicle brakes on")
    zone: Tuple[Tuple[float, float], ...] = param(
        (), unit="m", doc="operating zone, a simple polygon [[x, y], ...] in the map frame; empty: none")
    zone_sigmas: float = param(2.0, lo=0.0, hi=10.0, doc="the footprint grows by this many position sds in the zone")
    max_position_sd: float = param(1.0, lo=0.01, hi=100.0, unit="m",
                                   doc="with a zone: stop when the pose's horizontal sd exceeds this")
    pose_timeout: float = param(0.3, lo=0.01, hi=10.0, unit="s",
                                doc="with a zone: the pose silent this long stops; older, the DEM gives no braking slope")
    track_horizon: float = param(2.0, lo=0.0, hi=10.0, unit="s",
                                 doc="a moving obstacle is guarded where it will be over this time (tracks.py); 0: "
                                     "every return is taken as standing still")
    track_cluster_gap: float = param(0.3, lo=0.01, hi=5.0, unit="m",
                                     doc="neighbouring returns further apart than this belong to different things")
    track_max_extent: float = param(6.0, lo=0.05, hi=20.0, unit="m",
                                    doc="a cluster reaching further than this from its centroid (a wall, a row, the "
                                        "ground) is not tracked")
    track_max_range: float = param(15.0, lo=0.5, hi=200.0, unit="m", doc="clusters further away are not tracked")
    track_gate: float = param(0.3, lo=0.01, hi=5.0, unit="m",
                              doc="a cluster matches a track within this of its predicted position (plus "
                                  "track_max_speed times the time since it was seen)")
    track_max_speed: float = param(12.0, lo=0.1, hi=50.0, unit="m/s", doc="faster tracks are not believed")
    track_min_speed: float = param(0.5, lo=0.0, hi=50.0, unit="m/s", doc="slower tracks are taken as standing")
    track_window: float = param(0.8, lo=0.05, hi=10.0, unit="s", doc="the velocity is fitted over this long")
    track_min_obs: int = param(3, lo=2, hi=100, doc="centroids needed for a velocity")
    track_min_span: float = param(0.15, lo=0.0, hi=10.0, unit="s", doc="...spanning at least this long")
    track_max_residual: float = param(0.08, lo=0.001, hi=5.0, unit="m",
                                      doc="a centroid further than this from the fitted line: no velocity (a jump is "
                                          "not a motion)")
    track_min_travel: float = param(0.3, lo=0.0, hi=10.0, unit="m",
                                    doc="a track moves when its line travels this far over the window, beyond the "
                                        "cluster's own radius (a centroid wanders across a thing's visible face)")
    track_end_travel: float = param(0.9, lo=0.0, hi=20.0, unit="m",
                                    doc="...or when an end of its cluster (the first or last return) travels this far "
                                        "on a line (a machine's leading corner; a standing thing's ends slide round "
                                        "it as the vehicle passes)")
    track_min_points: int = param(3, lo=1, hi=1000, doc="smaller clusters are not tracked")
    track_shape_change: float = param(0.25, lo=0.01, hi=20.0, unit="m",
                                      doc="a cluster whose size changes more than this restarts its centroid's "
                                          "history")
    track_coast: float = param(0.5, lo=0.0, hi=10.0, unit="s", doc="an unseen track is kept this long")
    track_step: float = param(0.1, lo=0.01, hi=5.0, unit="m", doc="spacing of a moving obstacle's predicted copies")
    track_max_points: int = param(8, lo=1, hi=1000, doc="a moving cluster's points copied along its motion")
    track_clearance: float = param(0.2, lo=0.0, hi=5.0, unit="m",
                                   doc="a thing that has moved (and where it will be) is kept this much further away "
                                       "than a standing one")
    track_seen_margin: float = param(0.15, lo=0.0, hi=5.0, unit="m",
                                     doc="a point lies where a scan saw through when the rays passing within this of "
                                         "it reached this far beyond it")
    track_seen_angle: float = param(0.01, lo=0.0, hi=0.5, unit="rad",
                                    doc="...those rays widened by this, plus one ray (the odometry's heading error)")
    track_seen_points: int = param(2, lo=1, hi=1000,
                                   doc="a track moves only when this many of its points entered or left space a scan "
                                       "saw through")

    def tracks(self) -> TrackParams:
        """The moving obstacles' parameters (the ``track_*`` keys without their prefix)."""
        return TrackParams(**{f.name: getattr(self, "track_" + f.name) for f in fields(TrackParams)
                              if f.name != "max_tracks"})

    def __post_init__(self) -> None:
        if self.track_min_speed > self.track_max_speed:
            raise ValueError(f"'track_min_speed' = {self.track_min_speed} must not exceed 'track_max_speed' = "
                             f"{self.track_max_speed}")
        if self.warning_margin < self.margin:
            raise ValueError(f"'warning_margin' = {self.warning_margin} must not be below 'margin' = {self.margin}")
        if not self.margin <= self.creep_margin <= self.warning_margin:
            raise ValueError(f"'creep_margin' = {self.creep_margin} must lie between 'margin' = {self.margin} and "
                             f"'warning_margin' = {self.warning_margin}")
        if self.slow_decel > self.brake_decel:
            raise ValueError(f"'slow_decel' = {self.slow_decel} must not exceed 'brake_decel' = {self.brake_decel}")
        if not self.scanners:
            raise ValueError("'scanners' is empty: the guard needs at least one laser")
        if self.zone:
            check_zone(self.zone)


def check_zone(zone: Sequence[Sequence[float]]) -> None:
    """Raise ConfigError unless ``zone`` is a simple polygon of at least 3 finite vertices."""
    pts = np.asarray(zone, dtype=float)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) < 3:
        raise ConfigError(f"the operating zone needs at least 3 [x, y] vertices, got {len(pts)}")
    if not np.all(np.isfinite(pts)):
        raise ConfigError("the operating zone has a vertex that is not a finite number")
    n = len(pts)
    for i in range(n):
        for j in range(i + 1, n):
            if j == i + 1 or (i == 0 and j == n - 1):
                continue  # neighbours share a vertex
            if _segments_cross(pts[i], pts[(i + 1) % n], pts[j], pts[(j + 1) % n]):
                raise ConfigError(f"the operating zone is not a simple polygon: edge {i} crosses edge {j}")
    area = 0.5 * float(np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1]))
    if abs(area) < 1e-6:
        raise ConfigError("the operating zone has no area")


def _segments_cross(a, b, c, d) -> bool:
    def orient(p, q, r):
        return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])
    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    return (o1 * o2 <= 0.0) and (o3 * o4 <= 0.0) and not (o1 == o2 == o3 == o4 == 0.0)


def points_in_polygon(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Even-odd rule for each of the points (N x 2) against the polygon (M x 2)."""
    x, y = points[:, 0:1], points[:, 1:2]
    x0, y0 = poly[:, 0][None, :], poly[:, 1][None, :]
    x1, y1 = np.roll(poly[:, 0], -1)[None, :], np.roll(poly[:, 1], -1)[None, :]
    crosses = (y0 > y) != (y1 > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xc = x0 + (y - y0) * (x1 - x0) / (y1 - y0)
    return (np.count_nonzero(crosses & (x < xc), axis=1) % 2) == 1


def distance_to_edges(points: np.ndarray, poly: np.ndarray) -> np.ndarray:
    """Distance [m] from each point to the polygon's boundary."""
    a = poly
    b = np.roll(poly, -1, axis=0)
    ab = b - a
    denom = np.maximum(np.sum(ab * ab, axis=1), 1e-12)
    d = points[:, None, :] - a[None, :, :]
    u = np.minimum(np.maximum(np.sum(d * ab[None], axis=2) / denom[None], 0.0), 1.0)
    closest = a[None] + u[..., None] * ab[None]
    return np.min(np.hypot(*(points[:, None, :] - closest).transpose(2, 0, 1)), axis=1)


@dataclass
class Decision:
    action: int
    limit: float  # [m/s] speed limit (magnitude) on the request
    reason: str = ""
    field: str = ""  # "protective", "warning", "zone", "" (none)
    free: float = math.inf  # [m] free distance along the path
    protective: float = 0.0  # [m] protective field length at the measured speed
    protective_request: float = 0.0  # [m] ... at the requested speed (what must be clear to release a hold)
    warning: float = 0.0  # [m] warning field length at the requested speed
    nearest: Optional[Tuple[float, float]] = None  # the point touched first (base_link)
    scanner: str = ""  # which scanner saw it
    scan_stamp: float = math.nan  # [s] the scan that saw it
    direction: int = 0
    slope: float = 0.0  # [rad] downhill along the motion, used in the fields


@dataclass
class _Scan:
    stamp: float = -math.inf
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    counts: Tuple[int, int, int, int] = (0, 0, 0, 0)  # the last scan's rays: all, invalid, 0.0, beyond range_max
    error: str = ""  # a reason it cannot be used (no transform), or ""


@dataclass(frozen=True)
class Setpoint:
    speed: float
    handlebar: float
    brake: float


class Guard:
    """The guard's state: its inputs' latest values and the stop/hold/release cycle."""

    def __init__(self, p: GuardParams, vehicle: VehicleParams, heights=None) -> None:
        """``heights(x, y)`` [m] (arrays): the DEM in the map frame, if known (the braking slope)."""
        self.p, self.v = p, vehicle
        self.heights = heights
        self.fp = Footprint.from_vehicle(vehicle, p.padding)
        self.body = Footprint.from_vehicle(vehicle, 0.0)
        self.zone = np.asarray(p.zone, dtype=float) if p.zone else None
        self.scans: Dict[str, _Scan] = {s.topic: _Scan() for s in p.scanners}
        self.trackers: Dict[str, MotionTracker] = {s.topic: MotionTracker(p.tracks()) for s in p.scanners}
        self.ego: Optional[Tuple[float, float, float, float]] = None  # (t, x, y, yaw): odometric, from the states
        self._speeds = np.zeros(0)  # of the points of the last _points: 0 standing, else the track's speed
        self.state: Optional[Tuple[float, float, float]] = None  # (stamp, speed, handlebar)
        self.pose: Optional[Tuple[float, float, float, float, float]] = None  # (stamp, x, y, yaw, sd)
        self.slope_est: Optional[Tuple[float, float]] = None  # (t, pitch low-passed over slope_smoothing)
        self.mode = CLEAR  # CLEAR (incl. SLOW), STOP, HOLD, FAULT
        self.clear_since: Optional[float] = None
        self.release_t: Optional[float] = None
        self.last: Optional[Decision] = None
        self._free_cache = None  # (key, poses, Free) of the last sweep (see _free)
        self.stop_field = self.stop_reason = ""  # what started the current STOP or FAULT
        self.protective_stops = 0
        self.fault_stops = 0
        self.zone_stops = 0

    # ---------------------------------------------------------------- inputs
    def on_state(self, stamp: float, speed: float, handlebar: float) -> None:
        """The measured rear wheel speed [m/s, signed] and handlebar [rad]; the odometric pose
        (the moving obstacles' frame) is integrated with the previous state's."""
        if self.ego is None or self.state is None:
            self.ego = (stamp, 0.0, 0.0, 0.0)
        else:
            dt = stamp - self.ego[0]
            if 0.0 < dt <= 1.0:
                self.ego = (stamp,) + self._advance(self.ego[1:], self.state[1], self.state[2], dt)
            elif dt > 1.0:  # silent for long: the motion in between is unknown, the tracks too
                self.ego = (stamp,) + self.ego[1:]
                for tr in self.trackers.values():
                    tr.reset()
        self.state = (stamp, speed, handlebar)

    def _advance(self, pose, speed: float, handlebar: float, dt: float) -> Tuple[float, float, float]:
        """The bicycle model (fields.sweep's) over ``dt`` [s] (negative: back)."""
        x, y, yaw = pose
        w = speed * math.tan(self.v.steering.ratio * handlebar) / self.v.wheelbase
        mid = yaw + 0.5 * w * dt
        return x + speed * math.cos(mid) * dt, y + speed * math.sin(mid) * dt, yaw + w * dt

    def ego_at(self, stamp: float) -> Optional[Tuple[float, float, float]]:
        """The odometric pose at ``stamp``, from the last state's (at most 0.5 s away)."""
        if self.ego is None or self.state is None:
            return None
        dt = min(max(stamp - self.ego[0], -0.5), 0.5)
        return self._advance(self.ego[1:], self.state[1], self.state[2], dt)

    def on_pitch(self, stamp: float, pitch: float) -> None:
        """The vehicle's pitch [rad] (REP-103: positive nose down), from
        :class:`quadrivio_description.attitude.Attitude` (the IMU with the vehicle's own
        acceleration taken out)."""
        if self.slope_est is not None and stamp > self.slope_est[0] and self.p.slope_smoothing > 0.0:
            k = min(1.0, (stamp - self.slope_est[0]) / self.p.slope_smoothing)
            pitch = self.slope_est[1] + k * (pitch - self.slope_est[1])
        elif self.slope_est is not None and stamp <= self.slope_est[0]:
            return
        self.slope_est = (stamp, pitch)

    def on_pose(self, stamp: float, x: float, y: float, yaw: float, sd: float) -> None:
        """The predicted pose in the map frame and its horizontal standard deviation [m]."""
        self.pose = (stamp, x, y, yaw, sd)

    def on_scan(self, topic: str, stamp: float, points: Optional[ScanPoints], error: str = "") -> None:
        """A scan's points in base_link (``None`` with ``error``: it came but cannot be used,
        e.g. no transform). Self-returns (points inside the unpadded body) are left out."""
        sc = self.scans[topic]
        sc.stamp = stamp
        sc.error = error
        if points is None:
            sc.points = np.zeros((0, 2))
            return
        xy = points.xy
        if len(xy):
            xy = xy[~inside(self.body, xy)]
        sc.points = xy
        ego = self.ego_at(stamp)
        if ego is not None:
            self.trackers[topic].update(stamp, xy, ego, points.rays)
        sc.counts = (points.n_rays, points.n_invalid, points.n_zero, points.n_beyond)

    # ---------------------------------------------------------------- decide
    def pitch(self, now: float) -> Optional[float]:
        if self.slope_est is None or now - self.slope_est[0] > self.p.imu_timeout:
            return None
        return self.slope_est[1]

    def dem_slope(self, now: float, direction: int, speed: float, reaction: float) -> Optional[float]:
        """The DEM's mean downhill grade [rad] along the motion over the stopping distance
        from ``speed`` (None: no DEM or no fresh pose)."""
        if self.heights is None or self.pose is None or now - self.pose[0] > self.p.pose_timeout:
            return None
        _, x, y, yaw, _ = self.pose
        c, sn = direction * math.cos(yaw), direction * math.sin(yaw)
        slope = 0.0
        for _ in range(2):
            d = max(stopping_distance(speed, reaction, effective_decel(self.p.brake_decel, slope)) + self.p.margin,
                    self.p.step)
            h = self.heights(np.array([x, x + c * d]), np.array([y, y + sn * d]))
            slope = math.atan2(float(h[0] - h[1]), d)
        return slope

    def decide(self, now: float, req_speed: float, req_handlebar: float) -> Decision:
        """The guard's decision at ``now`` for a request (speed [m/s, signed], handlebar [rad])."""
        p = self.p
        fault = self._fault(now)
        st = self.state
        v_m = st[1] if st is not None else 0.0
        h_m = st[2] if st is not None else req_handlebar
        if abs(v_m) >= p.stop_speed:
            direction = 1 if v_m > 0 else -1
        else:
            direction = 0 if req_speed == 0.0 else (1 if req_speed > 0 else -1)
        if fault is None and direction != 0:
            fault = self._scanner_fault(now, direction)
        if fault is not None:
            return self._enter(Decision(FAULT, 0.0, fault, direction=direction), now)
        v = abs(v_m)
        slope = None
        if direction != 0:
            slope = self.dem_slope(now, direction, max(v, abs(req_speed)), p.brake_latency + p.scan_period)
        if slope is None:
            pitch = self.pitch(now)
            slope = p.slope_unknown if pitch is None else direction * pitch
        if direction == 0:  # standing, nothing requested: nothing to guard; a hold stays
            held = self.mode in (STOP, HOLD, FAULT)
            if held:
                self.mode, self.clear_since = HOLD, None
            d = Decision(HOLD if held else CLEAR, 0.0 if held else math.inf, "holding after a stop" if held else "",
                         slope=slope)
            self.last = d
            return d
        points, stamps, owners = self._points(now)
        age = max(0.0, now - min(stamps)) if stamps else 0.0
        a_brake = effective_decel(p.brake_decel, slope)
        a_slow = effective_decel(p.slow_decel, slope)
        t_prot = p.brake_latency + age
        t_warn = t_prot + p.scan_period
        v_req = abs(req_speed)
        d_prot = stopping_distance(v, t_prot, a_brake) + p.margin
        d_prot_req = stopping_distance(v_req, t_prot, a_brake) + p.margin
        d_warn = stopping_distance(max(v, v_req), t_warn, a_slow) + p.warning_margin
        poses, free = self._free(direction, h_m, req_handlebar, max(v, v_req), max(d_warn, d_prot) + p.step,
                                 points, stamps)
        d_free = free.distance - v * age  # the vehicle drove on since the scan
        who = owners[free.index] if free.index >= 0 else ""
        moving = float(self._speeds[free.index]) if free.index >= 0 else 0.0
        what = "obstacle" if moving == 0.0 else (f"moving obstacle ({moving:.1f} m/s, where it may be within "
                                                 f"{p.track_horizon:.1f} s)")
        limit = allowed_speed(d_free - p.warning_margin, t_warn, a_slow)
        if d_free >= p.creep_margin:
            limit = max(limit, p.creep_speed)
        d = Decision(CLEAR, limit, free=d_free,
                     protective=d_prot, protective_request=d_prot_req, warning=d_warn, nearest=free.point,
                     scanner=who, scan_stamp=self.scans[who].stamp if who else self._judged(now, direction),
                     direction=direction, slope=slope)
        if v >= p.stop_speed and d_free < d_prot:
            d.action, d.field = STOP, "protective"
            d.reason = (f"{what} {max(d_free, 0.0):.2f} m along the path, inside the protective field "
                        f"({d_prot:.2f} m at {v:.2f} m/s)")
            d.limit = 0.0
            return self._enter(d, now)
        if self.zone is not None:
            # the protective distance of the speed asked for too: a vehicle standing at the
            # edge must not be released toward it, to creep closer stop after stop
            z = self._zone_check(now, poses, max(d_prot, d_prot_req))
            if z:
                d.field, d.reason, d.limit = "zone", z, 0.0
                if v >= p.stop_speed:
                    d.action = STOP
                    return self._enter(d, now)
                d.action, self.mode, self.clear_since = HOLD, HOLD, None
                self.last = d
                return d
        if d.limit < v_req:
            d.field = "warning"
            d.reason = (f"{what} {max(d_free, 0.0):.2f} m along the path in the warning field: speed limited to "
                        f"{d.limit:.2f} m/s")
        return self._cycle(d, now, req_speed)

    def command(self, d: Decision, req_speed: float, req_handlebar: float, req_brake: float) -> Setpoint:
        """The setpoint to send for a request under decision ``d``."""
        if d.action in (STOP, HOLD, FAULT):
            hold = self.state[2] if self.state is not None else req_handlebar
            return Setpoint(0.0, hold, max(req_brake, self.p.stop_brake))
        v = max(-d.limit, min(d.limit, req_speed))
        return Setpoint(v, req_handlebar, req_brake)

    # -------------------------------------------------------------- helpers
    def _fault(self, now: float) -> Optional[str]:
        p = self.p
        if self.state is None:
            return "no vehicle state yet (vehicle/state)"
        age = now - self.state[0]
        if age > p.state_timeout:
            return f"vehicle state silent for {age:.2f} s (> {p.state_timeout} s)"
        if self.zone is not None:
            if self.pose is None:
                return "no pose yet (localization/predicted), needed for the operating zone"
            age = now - self.pose[0]
            if age > p.pose_timeout:
                return f"pose silent for {age:.2f} s (> {p.pose_timeout} s), needed for the operating zone"
        return None

    def _covers(self, s: ScannerParams, direction: int) -> bool:
        return s.covers == "both" or (s.covers == "forward") == (direction > 0)

    def _scanner_fault(self, now: float, direction: int) -> Optional[str]:
        p = self.p
        if not any(self._covers(s, direction) for s in p.scanners):  # a vehicle with one laser, reversing
            return f"no scanner covers {'forward' if direction > 0 else 'reverse'} motion"
        for s in p.scanners:
            if not self._covers(s, direction):
                continue
            sc = self.scans[s.topic]
            if sc.stamp == -math.inf:
                return f"no scan yet from {s.topic}"
            age = now - sc.stamp
            if age > p.scan_timeout:
                return f"{s.topic} silent for {age:.2f} s (> {p.scan_timeout} s)"
            if sc.error:
                return f"{s.topic}: {sc.error}"
            if sc.counts[1] / max(sc.counts[0], 1) > p.blind_fraction:  # invalid / all
                return blinded_reason(s.topic, *sc.counts)
        return None

    def _free(self, direction: int, h0: float, h1: float, speed: float, length: float, points: np.ndarray,
              stamps) -> tuple:
        """The sweep and its free distance; the same scans, direction and (to 0.01 rad) handlebar
        angles give the same answer, so the 50 Hz requests between two scans reuse it (the
        sweep is computed 0.5 m and 0.25 m/s longer and faster than asked, in steps)."""
        p = self.p
        key = (tuple(stamps), direction, round(h0, 2), round(h1, 2), math.ceil(speed / 0.25),
               math.ceil(length / 0.5))
        if self._free_cache is not None and self._free_cache[0] == key:
            return self._free_cache[1], self._free_cache[2]
        poses = sweep(direction, round(h0, 2), round(h1, 2), self.v.steering.max_rate,
                      0.25 * math.ceil(speed / 0.25), 0.5 * math.ceil(length / 0.5), p.step, self.v.wheelbase,
                      self.v.steering.ratio)
        free = free_distance(self.fp, poses, points, p.step)
        self._free_cache = (key, poses, free)
        return poses, free

    def _judged(self, now: float, direction: int) -> float:
        """With nothing in the sweep, the scan judged: the newest fresh one of the scanners
        guarding the motion (a later stop on the same scan was then entered by motion)."""
        newest = math.nan
        for s in self.p.scanners:
            sc = self.scans[s.topic]
            if self._covers(s, direction) and not sc.error and now - sc.stamp <= self.p.scan_timeout:
                newest = sc.stamp if math.isnan(newest) else max(newest, sc.stamp)
        return newest

    def _points(self, now: float):
        """Every fresh scanner's points (each guards whatever it sees, whichever direction it
        covers), their scans' stamps, and for each point its scanner."""
        chunks, stamps, owners, speeds = [], [], [], []
        for s in self.p.scanners:
            sc = self.scans[s.topic]
            if sc.error or now - sc.stamp > self.p.scan_timeout:
                continue
            chunks.append(sc.points)
            stamps.append(sc.stamp)
            owners += [s.topic] * len(sc.points)
            speeds.append(np.zeros(len(sc.points)))
            pr = self.trackers[s.topic].prediction
            if len(pr.xy) and self.trackers[s.topic].last_stamp == sc.stamp:
                chunks.append(pr.xy)
                owners += [s.topic] * len(pr.xy)
                speeds.append(pr.speed)
        pts = np.concatenate(chunks) if chunks else np.zeros((0, 2))
        self._speeds = np.concatenate(speeds) if speeds else np.zeros(0)
        return pts, stamps, owners

    def _zone_check(self, now: float, poses: np.ndarray, d_prot: float) -> str:
        _, x, y, yaw, sd = self.pose
        p = self.p
        if sd > p.max_position_sd:
            return f"position uncertain: sd {sd:.2f} m (> {p.max_position_sd} m) in the operating zone"
        grow = p.zone_sigmas * sd
        fp = Footprint(self.fp.front + grow, self.fp.rear + grow, self.fp.left + grow, self.fp.right + grow)
        s = np.arange(len(poses)) * p.step
        use = poses[s <= d_prot + p.step]
        c, sn = math.cos(yaw), math.sin(yaw)
        corners = []
        for px, py, th in use:
            corners.append(fp.corners(x + c * px - sn * py, y + sn * px + c * py, yaw + th))
        pts = np.concatenate(corners)
        inside = points_in_polygon(pts, self.zone)
        if not inside.all():
            return "the footprint would leave the operating zone within the protective distance"
        return ""

    def _enter(self, d: Decision, now: float) -> Decision:
        """A STOP or FAULT: counted once per episode; then HOLD once stopped."""
        if d.action == STOP and self.mode != STOP:
            if d.field == "zone":
                self.zone_stops += 1
            else:
                self.protective_stops += 1
        if d.action == FAULT and self.mode != FAULT:
            self.fault_stops += 1
        if self.mode != d.action:
            self.stop_field, self.stop_reason = d.field, d.reason
        self.mode = d.action
        self.clear_since = None
        self.release_t = None
        self.last = d
        return d

    def _cycle(self, d: Decision, now: float, req_speed: float) -> Decision:
        """Hold after a stop until the field has been clear for ``clear_time``, then release
        the limit at ``release_accel``."""
        p = self.p
        v_m = abs(self.state[1]) if self.state is not None else 0.0
        if self.mode in (STOP, FAULT):
            if v_m < p.stop_speed:
                self.mode = HOLD
            else:  # still braking for what started the stop (a field or a fault)
                d.action, d.limit = self.mode, 0.0
                d.field = self.stop_field
                d.reason = f"braking to a stop: {self.stop_reason}"
                self.last = d
                return d
        if self.mode == HOLD:
            clear = d.free >= d.protective_request
            if clear:
                if self.clear_since is None:
                    self.clear_since = now
                if now - self.clear_since >= p.clear_time:
                    self.mode, self.release_t = CLEAR, now
            else:
                self.clear_since = None
            if self.mode == HOLD:
                d.action, d.limit = HOLD, 0.0
                waited = 0.0 if self.clear_since is None else now - self.clear_since
                d.reason = (f"holding after a stop: field clear for {waited:.1f} of {p.clear_time} s" if clear else
                            d.reason or "holding after a stop: the field is not clear")
                self.last = d
                return d
        if self.release_t is not None:
            ramp = p.release_accel * (now - self.release_t)
            if ramp >= abs(req_speed) or ramp >= d.limit:
                self.release_t = None
            else:
                d.limit = ramp
                d.reason = d.reason or "releasing after a stop"
        d.action = SLOW if d.limit < abs(req_speed) - 1e-6 else CLEAR
        self.last = d
        return d


@dataclass(frozen=True)
class GuardNodeParams:
    """The guard node's own parameters (``config/guard.yaml``, beside :class:`GuardParams`)."""
    zone_file: str = param("", doc="YAML file with zone: [[x, y], ...] (map frame); empty: the parameters' zone")
    base_frame: str = param("base_link")
    request_timeout: float = param(0.25, lo=0.01, hi=10.0, unit="s",
                                   doc="a request older than this is not repeated as a stop on a scan")
    terrain_from_scenario: bool = param(True, doc="with a scenario whose terrain is known (a DEM), returns on it "
                                                  "are the ground, not obstacles")
    ground_tolerance: float = param(0.15, lo=0.0, hi=2.0, unit="m", doc="a return this close to the DEM is the ground")
    ground_position_sigmas: float = param(
        2.0, lo=0.0, hi=10.0, doc="...plus the DEM's gradient there times this many of the pose's horizontal sds "
                                  "(the terrain under a return drawn from a pose that is off)")
    ground_tolerance_max: float = param(
        0.3, lo=0.0, hi=2.0, unit="m", doc="the ground tolerance never exceeds this: keep it under the scan "
                                           "plane's height over the ground (0.57 m for the front laser)")
    ground_position_sd_min: float = param(
        0.5, lo=0.0, hi=10.0, unit="m",
        doc="the ground test takes the pose's horizontal sd as at least this: an estimate on rough ground can be "
            "off several of its own sds (the GNSS receiver's drift, a multipath burst let back in), and a return on "
            "a bump's face then looks like an obstacle")


def load_zone_file(path: str):
    """The ``zone`` of a YAML file, checked (ConfigError naming the file and the problem)."""
    data = load_yaml(path)
    if not isinstance(data, dict) or "zone" not in data:
        raise ConfigError(f"{path}: no 'zone: [[x, y], ...]' in it")
    if data.get("frame_id", "map") != "map":
        raise ConfigError(f"{path}: frame_id '{data['frame_id']}': the operating zone must be in the map frame")
    try:
        zone = tuple((float(x), float(y)) for x, y in data["zone"])
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{path}: 'zone' must be a list of [x, y] pairs: {exc}") from exc
    try:
        check_zone(zone)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from exc
    return zone
