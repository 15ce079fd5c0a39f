"""Run metrics (the ``metrics.json`` contract), from time series of a run.

Errors are horizontal, against the ground truth interpolated at each estimate's stamp
(linear in position, along the shortest arc in heading). The cross-track error is the
ground-truth position's distance to the reference path (segment-exact), over the part
of the run after the path was received and before the follower finished. A key that
cannot be computed (no ground truth in a real bag, no GPS...) is ``None``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, Optional

import numpy as np

CONTRACT_KEYS = ("scenario", "seed", "completed", "sim_duration_s", "wall_duration_s", "rtf", "loc_rmse_m",
                 "loc_p95_m", "loc_max_m", "loc_heading_rmse_deg", "pred_rmse_m", "gps_rmse_m", "gps_fix_fraction",
                 "xte_rmse_m", "xte_max_m", "max_lateral_accel_mps2")
# planned runs (a map and a goal): None in runs without them
PLANNED_KEYS = ("goal_position_error_m", "goal_heading_error_deg", "collisions", "path_length_m", "plan_time_s",
                "replans")


@dataclass
class Series:
    """Arrays of one kind of message, in time order."""
    t: np.ndarray
    cols: Dict[str, np.ndarray] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.t)

    def __getitem__(self, key: str) -> np.ndarray:
        return self.cols[key]

    @staticmethod
    def empty() -> "Series":
        return Series(np.zeros(0))

    @staticmethod
    def from_rows(rows, names) -> "Series":
        """Rows ``(t, value...)`` with the values' ``names``, ordered by time (stable)."""
        if not rows:
            return Series.empty()
        a = np.array(rows, dtype=float)
        a = a[np.argsort(a[:, 0], kind="stable")]
        return Series(a[:, 0], {n: a[:, i + 1] for i, n in enumerate(names)})


@dataclass
class RunData:
    ground_truth: Series  # t, x, y, yaw, vx (body), wz
    estimate: Series  # localization/odom: t, x, y, yaw
    predicted: Series  # localization/predicted: t, x, y, yaw
    gps: Series  # t, e, n (ENU of the fix), status
    path: Optional[np.ndarray]  # N x 2 reference path
    status: Series  # follower/status: t, status, progress
    lever: tuple = (0.0, 0.0)  # GPS antenna in base_link (x, y)
    setpoint: Series = field(default_factory=Series.empty)  # vehicle/setpoint/auto: t, speed, handlebar, brake
    vehicle: Series = field(default_factory=Series.empty)  # vehicle/state: t, speed, handlebar
    calibration: Series = field(default_factory=Series.empty)  # localization/calibration: t, <name>...
    goal: Optional[tuple] = None  # (x, y, yaw) the planner was asked for
    map: object = None  # quadrivio_navigation.maps.OccupancyGrid of /map
    planner: Series = field(default_factory=Series.empty)  # planner/status: t, state, planning_time, length
    path_poses: Optional[np.ndarray] = None  # N x 3 planned poses with the vehicle's heading
    footprint: object = None  # quadrivio_navigation.costmap.Footprint (no padding) for collisions
    guard: Series = field(default_factory=Series.empty)  # guard/status: t, action, limit, free, protective, ...
    actors: list = field(default_factory=list)  # ground_truth/actors: [(t, [(name, kind, shape, x, y, yaw, l, w)])]
    map_bodies: Optional[list] = None  # ground_truth/map_bodies: [(name, kind, shape, x, y, yaw, l, w)]; None: not recorded
    contacts: Optional[list] = None  # ground_truth/contacts: [(t, body, kind, speed)]; None: not recorded
    paths: list = field(default_factory=list)  # every path received: [(t, N x 2)] (replans)
    local_marks: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # local_obstacles' marks, all run
    gps_decisions: list = field(default_factory=list)  # localization/gps_decisions: [(fix t, used, reason, d2)]
    warnings: list = field(default_factory=list)  # what reading the recording found suspect (its clocks)


def _interp_pose(gt: Series, t: np.ndarray):
    """Ground truth x, y, yaw at times ``t`` (inside the ground truth's span only)."""
    inside = (t >= gt.t[0]) & (t <= gt.t[-1])
    yaw = np.unwrap(gt["yaw"])
    return (inside, np.interp(t, gt.t, gt["x"]), np.interp(t, gt.t, gt["y"]), np.interp(t, gt.t, yaw))


def _stats(errors: np.ndarray):
    if len(errors) == 0:
        return None, None, None
    return (float(np.sqrt(np.mean(errors ** 2))), float(np.percentile(errors, 95)), float(np.max(errors)))


def position_errors(gt: Series, est: Series) -> Optional[np.ndarray]:
    """Per-estimate ``[t, horizontal error, heading error (rad)]``."""
    if len(gt) < 2 or len(est) == 0:
        return None
    inside, x, y, yaw = _interp_pose(gt, est.t)
    if not inside.any():
        return None
    e = np.hypot(est["x"] - x, est["y"] - y)
    h = np.arctan2(np.sin(est["yaw"] - yaw), np.cos(est["yaw"] - yaw))
    return np.column_stack([est.t, e, h])[inside]


def gps_errors(gt: Series, gps: Series, lever) -> Optional[np.ndarray]:
    """Per-fix ``[t, horizontal error]`` of the fixes that claim a fix, against the true antenna."""
    if len(gt) < 2 or len(gps) == 0:
        return None
    ok = gps["status"] >= 0
    t = gps.t[ok]
    inside, x, y, yaw = _interp_pose(gt, t)
    ax = x + np.cos(yaw) * lever[0] - np.sin(yaw) * lever[1]
    ay = y + np.sin(yaw) * lever[0] + np.cos(yaw) * lever[1]
    e = np.hypot(gps["e"][ok] - ax, gps["n"][ok] - ay)
    return np.column_stack([t, e])[inside]


def cross_track(gt: Series, path: Optional[np.ndarray], t0: float, t1: float) -> Optional[np.ndarray]:
    """``[t, distance to the path]`` of the ground truth between ``t0`` and ``t1``."""
    if path is None or len(path) < 2 or len(gt) == 0:
        return None
    m = (gt.t >= t0) & (gt.t <= t1)
    if not m.any():
        return None
    a, b = path[:-1], path[1:]
    ab = b - a
    denom = np.maximum((ab ** 2).sum(1), 1e-12)
    ax, ay, abx, aby = a[:, 0], a[:, 1], ab[:, 0], ab[:, 1]
    t, xs, ys = gt.t[m], np.asarray(gt["x"][m], float), np.asarray(gt["y"][m], float)
    d = np.empty(len(t))
    rows = max(1, 250_000 // len(ax))  # points per block: a block's arrays stay a few MB
    for i in range(0, len(t), rows):  # every point against every segment, the same arithmetic per pair
        x, y = xs[i:i + rows, None], ys[i:i + rows, None]
        u = np.clip(((x - ax) * abx + (y - ay) * aby) / denom, 0.0, 1.0)
        d[i:i + rows] = np.sqrt(np.min((ax + u * abx - x) ** 2 + (ay + u * aby - y) ** 2, axis=1))
    return np.column_stack([t, d])


def cross_track_replanned(gt: Series, paths: list, t0: float, t1: float) -> Optional[np.ndarray]:
    """Cross-track error against the path in force at each time: each path from its stamp
    to the next one's (a replan replaces the route from where the vehicle is)."""
    pieces = []
    for k, (tp, xy) in enumerate(paths):
        end = paths[k + 1][0] if k + 1 < len(paths) else math.inf
        lo, hi = max(t0, tp), min(t1, end)
        if hi > lo:
            xt = cross_track(gt, xy, lo, hi)
            if xt is not None and hi == end:
                xt = xt[xt[:, 0] < end]  # a pose at the replan's stamp is the next path's, not counted twice
            if xt is not None and len(xt):
                pieces.append(xt)
    return np.concatenate(pieces) if pieces else None


def cross_track_in_force(run: "RunData", t0: float, t1: float) -> Optional[np.ndarray]:
    """The ground truth's cross-track error against the path the vehicle followed at each
    time: every path received (:func:`cross_track_replanned`) when it was replanned, else
    the one path. Measured against the last path only, a run that replanned read the
    distance of its first stretch to a route it never drove (tens of metres)."""
    if len(run.paths) > 1:
        return cross_track_replanned(run.ground_truth, run.paths, t0, t1)
    return cross_track(run.ground_truth, run.path, t0, t1)


def settle_completed(m: Dict[str, object], end: Optional[str], outcome: Optional[str]) -> None:
    """``completed`` of a run that was to follow a path to its end (``run.end: path_done``)
    but whose follower never reported (its planner failed, or time ran out first): False,
    from the run's outcome. Computed from the recording alone it is null, which is right
    for a recording without a follower but read as "not a run that completes": a campaign's
    mean then left out the seeds whose plan failed (a goal in a tree showed a blank
    instead of 0). Unchanged without an outcome (a bag analysed on its own)."""
    if m.get("completed") is None and end == "path_done" and outcome:
        m["completed"] = outcome == "completed"


def following_window(status: Series, default: tuple) -> tuple:
    """From the first FOLLOWING status to the first DONE/ABORTED (or the default span)."""
    if len(status) == 0:
        return default
    st = status["status"]
    following = np.flatnonzero(st == 1)
    t0 = status.t[following[0]] if len(following) else default[0]
    ended = np.flatnonzero((st == 2) | (st == 3))
    t1 = status.t[ended[0]] if len(ended) else default[1]
    return t0, t1


def follower_cross_track(status: Series) -> Optional[np.ndarray]:
    """(t, |cross-track error|) that the follower itself reported while FOLLOWING: the distance
    of the *estimated* pose to its path (``/follower/status``). Unlike ``cross_track`` it needs
    no ground truth, so it is what a recording of the real vehicle says about tracking; beside
    the true one it separates the follower's share from the localization's. None without."""
    if len(status) == 0 or "cross_track" not in status.cols:
        return None
    xt = np.asarray(status["cross_track"], float)
    on = (status["status"] == 1) & np.isfinite(xt)
    if not on.any():
        return None
    return np.column_stack([status.t[on], np.abs(xt[on])])


def collision_events(gt: Series, grid, footprint, lethal: int = 65) -> Optional[int]:
    """Times the true footprint went from touching no occupied cell to touching one
    (ground-truth samples against the map's cells at or above ``lethal``)."""
    if grid is None or footprint is None or len(gt) == 0:
        return None
    hits = touching(gt, grid, footprint, lethal)
    return int(np.count_nonzero(hits & ~np.concatenate([[False], hits[:-1]])))


def touching(gt: Series, grid, footprint, lethal: int = 65) -> np.ndarray:
    """Whether the footprint at each ground-truth pose overlaps a cell of ``grid`` at or above
    ``lethal`` (costmap.footprint_cells' cells), a bool per pose."""
    from quadrivio_navigation.costmap import footprint_cells

    from .obstacle_metrics import cover_discs

    occupied = grid.data >= lethal
    hits = np.zeros(len(gt), dtype=bool)
    if not occupied.any():
        return hits
    h, w = occupied.shape
    res = grid.resolution
    # Poses far from every occupied cell touch none: a cell footprint_cells returns has
    # its centre within the rectangle grown by half a cell's diagonal, so within ``disc`` of
    # the centre of one of the discs covering it, and that centre within half a diagonal of
    # its own cell's centre. The distance transform (cell centre to the nearest occupied
    # cell's centre) at those cells leaves the exact test to the poses near something (an
    # orchard run: a disc about base_link left it 0.07 s of 0.1; the lanes are narrower than
    # the vehicle is long).
    from scipy.ndimage import distance_transform_edt

    half = 0.5 * math.sqrt(2.0) * res
    clear = distance_transform_edt(~occupied) * res
    xs, ys, yaws = (np.asarray(gt[k], float) for k in ("x", "y", "yaw"))
    centres, disc = cover_discs(footprint, xs, ys, yaws, grow=half)
    far = np.ones(len(xs), dtype=bool)
    for cx, cy in centres:
        gxs, gys, _ = grid.to_grid_frame(cx, cy, 0.0)
        with np.errstate(invalid="ignore"):
            r, c = np.floor(gys / res), np.floor(gxs / res)
            on = (r >= 0) & (c >= 0) & (r < h) & (c < w)
        ok = np.zeros(len(xs), dtype=bool)
        ok[on] = clear[r[on].astype(int), c[on].astype(int)] > disc + half + 1e-9
        far &= ok
    for i in np.flatnonzero(~far):
        gx, gy, gth = grid.to_grid_frame(float(xs[i]), float(ys[i]), float(yaws[i]))
        rows, cols = footprint_cells(footprint, gx, gy, gth, res)
        keep = (rows >= 0) & (cols >= 0) & (rows < h) & (cols < w)
        hits[i] = occupied[rows[keep], cols[keep]].any()
    return hits


def planned_metrics(run: RunData) -> Dict[str, object]:
    """The PLANNED_KEYS of a run that planned to a goal; None where not applicable."""
    m: Dict[str, object] = {k: None for k in PLANNED_KEYS}
    gt = run.ground_truth
    if run.goal is not None and len(gt):
        gx, gy, gyaw = run.goal
        x, y, yaw = float(gt["x"][-1]), float(gt["y"][-1]), float(gt["yaw"][-1])
        m["goal_position_error_m"] = math.hypot(x - gx, y - gy)
        m["goal_heading_error_deg"] = abs(math.degrees(math.atan2(math.sin(yaw - gyaw), math.cos(yaw - gyaw))))
    if run.map is not None:
        m["collisions"] = collision_events(gt, run.map, run.footprint)
    found = run.planner["state"] == 2 if len(run.planner) else np.zeros(0, bool)
    if found.any():  # the planner made the path (not a reference path's publisher)
        m["plan_time_s"] = float(run.planner["planning_time"][found][-1])
        if len(run.paths) > 1:
            m["path_length_m"] = route_length([xy for _, xy in run.paths])
        elif run.path_poses is not None and len(run.path_poses) > 1:
            m["path_length_m"] = route_length([run.path_poses[:, :2]])
        m["replans"] = max(len(run.paths) - 1, 0)
    return m


def _arc_to_nearest(xy: np.ndarray, point) -> float:
    """Arc length along the polyline ``xy`` to its point nearest ``point`` (the first such)."""
    a, b = xy[:-1], xy[1:]
    ab = b - a
    seg = np.hypot(ab[:, 0], ab[:, 1])
    u = np.clip(((point[0] - a[:, 0]) * ab[:, 0] + (point[1] - a[:, 1]) * ab[:, 1])
                / np.maximum(seg ** 2, 1e-12), 0.0, 1.0)
    d2 = (a[:, 0] + u * ab[:, 0] - point[0]) ** 2 + (a[:, 1] + u * ab[:, 1] - point[1]) ** 2
    k = int(np.argmin(d2))
    return float(np.sum(seg[:k]) + u[k] * seg[k])


def route_length(paths: list) -> float:
    """The length of the route a run was planned along: each path up to where the next one
    (a replan, which starts from the vehicle's predicted pose on it) took over, then the last
    path whole. A replan's own length alone would say a 60 m route was 12 m long."""
    total = 0.0
    for k, xy in enumerate(paths):
        xy = np.asarray(xy, float)
        if len(xy) < 2:
            continue
        if k + 1 < len(paths) and len(paths[k + 1]):
            total += _arc_to_nearest(xy, np.asarray(paths[k + 1], float)[0])
        else:
            total += float(np.sum(np.hypot(np.diff(xy[:, 0]), np.diff(xy[:, 1]))))
    return total


def cpu_metrics(cpu_s: Optional[float], sim_s: Optional[float], wall_s: Optional[float],
                cores: Optional[int]) -> Dict[str, Optional[float]]:
    """A run's speed read against its limit: ``stack_cpu_s_per_sim_s`` (CPU seconds of every
    process of the run per simulated second) and ``stack_efficiency``, the achieved factor
    over the CPU-bound one (cores / CPU s per simulated s), which is the share of the
    machine's cores the run kept busy: near 1, more speed needs less work, not more waiting."""
    out: Dict[str, Optional[float]] = {"stack_cpu_s_per_sim_s": None, "stack_efficiency": None}
    if not (cpu_s and sim_s and sim_s > 0.0):
        return out
    out["stack_cpu_s_per_sim_s"] = cpu_s / sim_s
    if wall_s and wall_s > 0.0 and cores:
        achieved = sim_s / wall_s
        limit = cores / out["stack_cpu_s_per_sim_s"]
        out["stack_efficiency"] = achieved / limit
    return out


def fix_time(t: np.ndarray, status: np.ndarray, span) -> tuple:
    """(fraction of the run's time with a fix, longest time without one [s]). Time, not
    messages: a receiver that publishes nothing for 27 s (as much as one that says "no fix")
    is 27 s without a fix. The receiver's own period (the median interval of its valid
    fixes) is the time a fix covers; a gap counts as without a fix for what exceeds 1.5 of
    it, as do the run's start before the first fix and its end after the last."""
    t0, t1 = span
    if not t1 > t0:
        return None, None
    valid = np.asarray(t, float)[np.asarray(status) >= 0]
    if not len(valid):
        return 0.0, float(t1 - t0)
    period = float(np.median(np.diff(valid))) if len(valid) > 1 else float(t1 - t0)
    gaps = np.diff(np.concatenate([[t0], valid, [t1]]))
    without = float(np.sum(np.maximum(0.0, gaps - 1.5 * period)))
    return max(0.0, 1.0 - without / (t1 - t0)), float(gaps.max())


def compute(run: RunData, scenario: Optional[str] = None, seed: Optional[int] = None,
            wall_duration: Optional[float] = None, vehicle=None) -> Dict[str, object]:
    """The metrics of a run; with ``vehicle`` (VehicleParams) also the obstacle keys
    (:mod:`quadrivio.obstacle_metrics`: contacts, clearance, the guard's stops)."""
    gt = run.ground_truth
    m: Dict[str, object] = {k: None for k in CONTRACT_KEYS}
    m["scenario"], m["seed"] = scenario, seed
    spans = [s.t for s in (gt, run.estimate, run.status) if len(s)]
    if spans:
        t_first = min(float(s[0]) for s in spans)
        t_last = max(float(s[-1]) for s in spans)
        m["sim_duration_s"] = t_last - t_first
    if wall_duration:
        m["wall_duration_s"] = wall_duration
        if m["sim_duration_s"]:
            m["rtf"] = float(m["sim_duration_s"]) / wall_duration
    st = run.status
    m["completed"] = bool(np.any(st["status"] == 2)) if len(st) else None  # no follower: not a run that completes
    pe = position_errors(gt, run.estimate)
    if pe is not None:
        m["loc_rmse_m"], m["loc_p95_m"], m["loc_max_m"] = _stats(pe[:, 1])
        m["loc_heading_rmse_deg"] = math.degrees(float(np.sqrt(np.mean(pe[:, 2] ** 2))))
        settled = pe[pe[:, 0] >= pe[0, 0] + 10.0]
        if len(settled):
            m["loc_rmse_after_10s_m"] = float(np.sqrt(np.mean(settled[:, 1] ** 2)))
            m["loc_heading_rmse_after_10s_deg"] = math.degrees(float(np.sqrt(np.mean(settled[:, 2] ** 2))))
    pp = position_errors(gt, run.predicted)
    if pp is not None:
        m["pred_rmse_m"] = _stats(pp[:, 1])[0]
    if len(run.gps):
        ends = [s.t for s in (run.gps, gt, run.estimate) if len(s)]
        span = (min(float(e[0]) for e in ends), max(float(e[-1]) for e in ends))
        m["gps_fix_fraction"], m["gps_longest_gap_s"] = fix_time(run.gps.t, run.gps["status"], span)
        ge = gps_errors(gt, run.gps, run.lever)
        if ge is not None and len(ge):
            m["gps_rmse_m"] = _stats(ge[:, 1])[0]
    if run.gps_decisions:  # what the localization did with the fixes (a recording of it, or a replay)
        m["gps_fixes_used"] = sum(1 for d in run.gps_decisions if d[1])
        for reason in sorted({d[2] for d in run.gps_decisions if not d[1]}):
            m[f"gps_fixes_rejected_{reason.replace(' ', '_')}"] = sum(1 for d in run.gps_decisions
                                                                      if not d[1] and d[2] == reason)
    if len(gt):
        t0, t1 = following_window(st, (float(gt.t[0]), float(gt.t[-1])))
        xt = cross_track_in_force(run, t0, t1)
        if xt is not None and len(xt):
            m["xte_rmse_m"] = float(np.sqrt(np.mean(xt[:, 1] ** 2)))
            m["xte_max_m"] = float(np.max(xt[:, 1]))
        lat = np.abs(gt["vx"] * gt["wz"])  # a_y = v omega for the rear axle centre
        m["max_lateral_accel_mps2"] = float(np.max(lat)) if len(lat) else None
    m["xte_est_rmse_m"] = m["xte_est_max_m"] = None
    xe = follower_cross_track(st)
    if xe is not None:
        m["xte_est_rmse_m"] = float(np.sqrt(np.mean(xe[:, 1] ** 2)))
        m["xte_est_max_m"] = float(np.max(xe[:, 1]))
    m.update(planned_metrics(run))
    if vehicle is not None:
        from .obstacle_metrics import obstacle_metrics

        m.update(obstacle_metrics(run, vehicle))
    return m
