"""Global planner node: a path from where the vehicle is to a goal on the map.

Parameters (private, ``config/planner.yaml``, :class:`quadrivio_navigation.planning.PlannerParams`;
a scenario's ``planner:`` section overrides), and:

* ``~map_file`` (str, ""): plan on this map_server map instead of the ``map`` topic;
* ``~frame_id`` (str, "map"): the planning frame; goals in another frame are refused;
* ``~terrain_from_scenario`` (bool, true): with a scenario whose ``sim: terrain:`` is a DEM
  or procedural ground, add its slope cost and treat slopes steeper than the roll-over
  monitor's warning limit as obstacles.

* ``~check_rate`` (Hz, 2; 0: never), ``~check_horizon`` (m, 25), ``~retry`` (s, 2): how
  often the remaining path is checked against ``local_obstacles``, how far ahead, and how
  often a blocked vehicle tries again; ``~detour_wait`` (s, 10), ``~detour_margin`` (m, 5): a
  way round longer than the blocked path by more than the margin is put off (BLOCKED, "waiting
  up to ... s for it to clear", the old path kept: the guard stops the vehicle short of what
  blocks it) until the path clears (FOUND, "the path cleared: going on") or has stayed blocked
  that long, and is then planned from where the vehicle stands
  (:class:`quadrivio_navigation.replanning.DetourWait`).

Subscribes: ``map`` (nav_msgs/OccupancyGrid), ``move_base_simple/goal``
(geometry_msgs/PoseStamped, rviz's 2D Nav Goal; a new goal replans at once, cancelling a
plan under way), ``localization/odom`` (nav_msgs/Odometry, the start),
``localization/predicted`` (nav_msgs/Odometry, where a replan starts), ``local_obstacles``
(nav_msgs/OccupancyGrid, the local obstacle layer: when the remaining path's footprint
touches a marked cell, the planner replans from the predicted pose on the map with the
layer's marks added; with no path it reports BLOCKED, keeps the old path (the obstacle
guard holds the vehicle) and retries every ``~retry`` s; a goal covered by marks is BLOCKED
too), ``guard/status`` (how long the guard has held the vehicle); these three from the
first goal on (in lockstep from the start).
Publishes: ``planner/path`` (nav_msgs/Path, latched: each pose's orientation is the
vehicle's heading, so a step pointing against it is driven in reverse), ``planner/status``
(quadrivio_navigation/PlannerStatus, latched: IDLE with what it waits for, PLANNING,
FOUND, FAILED with the reason; planning time, time to the first solution, cost, length,
cusps). A goal outside the map, in collision or unreachable, or a start in collision,
gives FAILED with the reason, in the log too, and no path.
Services: ``~plan`` (quadrivio_navigation/PlanPath): plan between two given poses without
publishing anything.

In lockstep (``sim.launch lockstep:=true``) a plan takes no sim time, as in the closed loop
in one process: the simulator's round waits for the planner's thread, and the lattice stops
at a number of expansions (:func:`quadrivio_navigation.planning.repeatable`) instead of its
wall-clock budget, so that a planned run repeats message for message. A replan then starts
where the vehicle is (it does not move while the planner works).
"""

from __future__ import annotations

import math
import queue
import threading
import time
from typing import Optional, Tuple

import numpy as np
import rospy
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import OccupancyGrid, Odometry
from nav_msgs.msg import Path as PathMsg

from quadrivio_runtime.ros import init_node, lockstep
from quadrivio_runtime.ros.params import (fatal, node_params, private_params, split_params, vehicle_params,
                                             with_scenario)
from quadrivio_runtime.ros.timer import guarded_timer, input_guard, publish

from ..maps import MapError, OccupancyGrid as Grid, grid_warnings, load_map
from ..msg import PlannerStatus
from ..planning import PlannerParams, Planner, PlanResult, path_length, repeatable
from ..replanning import (DetourWait, HeldPoints, PlannerNodeParams, blocked_reason, known_distance, mark_discs,
                          merge_local, overtaken, remaining_length, replan_start)
from ..srv import PlanPath, PlanPathResponse
from .conversions import path_msg, pose_stamped, yaw_of
from .site_inputs import scenario_terrain, site_frame


NodeParams = PlannerNodeParams


def grid_from_msg(m: OccupancyGrid) -> Grid:
    info = m.info
    if info.width == 0 or info.height == 0 or not info.resolution > 0:
        raise MapError(f"map message of {info.width} x {info.height} cells of {info.resolution} m is empty")
    if len(m.data) != info.width * info.height:
        raise MapError(f"map message has {len(m.data)} cells, expected {info.width} x {info.height}")
    data = np.asarray(m.data, dtype=np.int8).reshape(info.height, info.width)
    o = info.origin
    return Grid(data, float(info.resolution), (o.position.x, o.position.y, yaw_of(o.orientation)))


class PlannerNode:
    def __init__(self) -> None:
        mine, rest = split_params(private_params(), NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, mine)
        self.p: PlannerParams = with_scenario(node_params(PlannerParams, rest), "planner")
        self.vehicle = vehicle_params()
        # in lockstep a plan takes no sim time (the round makes it: see _drain) and is bounded by
        # expansions, not by the wall clock, so that it ends alike in every run
        self.member = lockstep.member()
        if self.member is not None:
            self.p = repeatable(self.p)
        self.heights, self.rollover = self._terrain()
        self.lock = threading.Lock()  # one plan at a time (worker or service)
        self.planner: Optional[Planner] = None
        self.start: Optional[Odometry] = None
        self.goal: Optional[PoseStamped] = None
        self.jobs: "queue.Queue[Tuple[str, object]]" = queue.Queue()
        self.cancel = threading.Event()
        self.status = PlannerStatus()
        self.map_warnings: Tuple[str, ...] = ()  # the map's, said in every status
        self.pub_path: Optional[rospy.Publisher] = None  # advertised at the first path (see _publish_path)
        self.pub_status = rospy.Publisher("planner/status", PlannerStatus, queue_size=5, latch=True)
        self._set_status(PlannerStatus.IDLE, "waiting for a map" if not self.node_params.map_file else "loading the map")
        if self.node_params.map_file:
            try:
                grid = load_map(self.node_params.map_file, site_frame())
            except MapError as exc:
                fatal(f"cannot load the map: {exc}")
            rospy.loginfo("%s", grid.summary)
            self.jobs.put(("map", grid))
        else:
            rospy.Subscriber("map", OccupancyGrid, self._on_map, queue_size=1)
        rospy.Subscriber("move_base_simple/goal", PoseStamped, self._on_goal, queue_size=5)
        self.guard = input_guard()
        rospy.Subscriber("localization/odom", Odometry, self._on_odom, queue_size=1)
        self.local: Optional[Grid] = None  # the local obstacle layer's newest grid
        self.current: Optional[Tuple[float, float, float]] = None  # predicted pose (map)
        self.speed = 0.0  # [m/s] predicted
        self.known: Optional[np.ndarray] = None  # distance [m] of each static cell to the map's obstacles
        self.held_since: Optional[float] = None  # the obstacle guard holds the vehicle since
        self.held_points = HeldPoints()  # ...for these points (map)
        self.held_replan = False  # the next replan is because of the hold
        self.path_poses: Optional[np.ndarray] = None  # the published path
        self.static_grid: Optional[Grid] = None
        self.blocked_since: Optional[float] = None
        self.last_try = -math.inf
        self.replans = 0
        self.block_why = ""  # what blocked the path (BLOCKED retries with it)
        self.detour = DetourWait(self.node_params.detour_wait, self.node_params.detour_margin)  # or wait?
        self.last_found: tuple = (None, None, None)  # the start, goal and plan of the path in force
        # [s] wall, a replan's (building the map's planner included); none in lockstep
        self.replan_time = self.p.budget + 1.5 if self.member is None else 0.0
        self.watching = False  # subscribed to what replanning reads (_watch)
        self.watch_lock = threading.Lock()
        if self.node_params.check_rate > 0.0:
            guarded_timer(1.0 / self.node_params.check_rate, self._check, "path check")
            if self.member is not None:  # lockstep counts a member's messages from its subscriptions at the start
                self._watch()
        rospy.Service("~plan", PlanPath, self._on_plan_service)
        if self.member is None:
            self.worker = threading.Thread(target=self._work, name="planner", daemon=True)
            self.worker.start()
        else:  # the round's own thread plans once the round's messages and timers are handled
            self.member.add_drain(self._drain)
        rospy.loginfo("planner: %s, budget %.1f s, reverse %s, turning radius %.2f m", self.p.planner, self.p.budget,
                      self.p.reverse, (self.p.turning_radius or self.vehicle.min_turning_radius) * self.p.radius_margin)

    # ------------------------------------------------------------------ inputs
    def _terrain(self):
        """Heights of the scenario's simulated terrain (for slope cost), or None."""
        from ..rollover import RolloverParams

        return scenario_terrain("planner (slope cost)", self.node_params.terrain_from_scenario), RolloverParams()

    def _on_map(self, m: OccupancyGrid) -> None:
        try:
            grid = grid_from_msg(m)
        except MapError as exc:
            rospy.logerr("ignored a map: %s", exc)
            return
        grid.warnings = grid_warnings(grid.data, f"the map on {rospy.resolve_name('map')}")
        self.jobs.put(("map", grid))

    def _on_odom(self, m: Odometry) -> None:
        p, q = m.pose.pose.position, m.pose.pose.orientation
        if not self.guard.check("localization/odom", m.header.stamp.to_sec(), rospy.get_time(),
                                p.x, p.y, q.x, q.y, q.z, q.w):
            return  # the start stays the last good estimate
        self.start = m
        if self.status.state == PlannerStatus.IDLE and self.goal is not None and self.planner is not None:
            self.jobs.put(("goal", self.goal))

    def _on_local(self, m: OccupancyGrid) -> None:
        try:
            self.local = grid_from_msg(m)
        except MapError as exc:
            self.guard.reject("local_obstacles", "malformed grid", str(exc))

    def _on_predicted(self, m: Odometry) -> None:
        p, q = m.pose.pose.position, m.pose.pose.orientation
        if self.guard.check("localization/predicted", m.header.stamp.to_sec(), rospy.get_time(), p.x, p.y, q.z, q.w):
            self.current = (p.x, p.y, yaw_of(q))
            self.speed = m.twist.twist.linear.x if math.isfinite(m.twist.twist.linear.x) else 0.0

    def _on_guard(self, m) -> None:
        held = m.action in (m.STOP, m.HOLD) or (m.speed_limit < 0.05 and abs(m.requested_speed) > 0.1)
        self.held_points.update(held, self.current, (m.nearest.x, m.nearest.y) if m.has_nearest else None)
        if not held:
            self.held_since = None
        elif self.held_since is None:
            self.held_since = m.header.stamp.to_sec()

    def _check(self, _event) -> None:
        """Is the remaining path (or the goal) blocked by the local layer? Then replan."""
        st = self.status.state
        if self.local is None or self.current is None or self.goal is None or self.planner is None:
            return
        if st == PlannerStatus.BLOCKED and self.detour.waiting and self.path_poses is not None:
            # for the path to clear (the guard stops the vehicle short of what blocks it)
            why = blocked_reason(self.path_poses, self.current, self.local, self.planner.footprint,
                                 self.node_params.check_horizon, self.static_grid, self.known,
                                 self.node_params.known_tolerance)
            now = rospy.get_time()
            if not why:
                rospy.loginfo("planner: the path cleared, %.1f s after it was blocked: going on",
                              now - self.detour.since)
                self.detour.resume(now)
                self._resume()
            elif self.detour.left(now) <= 0.0:  # the way round, from where the guard holds the vehicle: kept
                self.held_replan = True          # held_clearance from what it held it for, as after held_replan
                self.jobs.put(("replan", why))
            return
        if st == PlannerStatus.BLOCKED:
            if rospy.get_time() - self.last_try >= self.node_params.retry:
                self.jobs.put(("replan", self.block_why))
            return
        if st != PlannerStatus.FOUND or self.path_poses is None:
            return
        why = blocked_reason(self.path_poses, self.current, self.local, self.planner.footprint,
                             self.node_params.check_horizon, self.static_grid, self.known, self.node_params.known_tolerance)
        now = rospy.get_time()
        if not why and self.held_since is not None and now - self.held_since >= self.node_params.held_replan and \
                now - self.last_try >= self.node_params.retry:
            why = f"the obstacle guard has held the vehicle for {now - self.held_since:.0f} s"
            self.held_replan = True
        elif why:
            self.detour.blocked(now)
        if why:
            self.jobs.put(("replan", why))

    def _watch(self) -> None:
        """Subscribe what replanning reads (the local layer, the predicted pose, the guard's
        status), from the first goal on: a run that follows a path and has no goal paid 0.02 CPU
        s per simulated second for them (the pose at 50 Hz, the guard at 10)."""
        with self.watch_lock:
            if self.watching or self.node_params.check_rate <= 0.0:
                return
            self.watching = True
        from ..msg import GuardStatus

        rospy.Subscriber("local_obstacles", OccupancyGrid, self._on_local, queue_size=1)
        rospy.Subscriber("localization/predicted", Odometry, self._on_predicted, queue_size=1)
        rospy.Subscriber("guard/status", GuardStatus, self._on_guard, queue_size=5)

    def _on_goal(self, m: PoseStamped) -> None:
        self._watch()
        self.cancel.set()  # a plan under way is for an old goal
        self.jobs.put(("goal", m))

    # ------------------------------------------------------------------ worker
    def _work(self) -> None:
        while not rospy.is_shutdown():
            try:
                kind, item = self.jobs.get(timeout=0.5)
            except queue.Empty:
                continue
            try:
                self._job(kind, item)
            finally:
                self.jobs.task_done()

    def _drain(self) -> None:
        """Lockstep: the jobs the round's messages and timers gave, made in the round (a
        thread would read the start or the layer while the round still delivers them)."""
        while True:
            try:
                kind, item = self.jobs.get_nowait()
            except queue.Empty:
                return
            try:
                self._job(kind, item)
            finally:
                self.jobs.task_done()

    def _job(self, kind: str, item) -> None:
        try:
            if kind == "map":
                self.map_warnings = tuple(item.warnings)
                for warning in self.map_warnings:
                    rospy.logwarn("planner: %s", warning)
                self._build(item)
                if self.goal is not None:
                    self._plan_goal(self.goal)
            elif kind == "replan":
                if self.jobs.empty():  # a newer goal or map first
                    self._replan(item)
            else:
                # only the newest goal matters (and a replan queued behind it is for the old one)
                while True:
                    try:
                        k2, i2 = self.jobs.get_nowait()
                    except queue.Empty:
                        break
                    try:
                        if k2 == "map":
                            self._build(i2)
                        elif k2 == "goal":
                            item = i2
                    finally:
                        self.jobs.task_done()
                self.goal = item
                self.cancel.clear()
                self._plan_goal(item)
        except Exception as exc:  # noqa: BLE001 - a planning bug must not end the node's planning
            rospy.logerr("planner: %s failed: %r", kind, exc)
            self._set_status(PlannerStatus.FAILED, f"internal error: {exc!r}")

    def _replan(self, why: str) -> None:
        """Plan from the predicted pose on the map with the local layer's marks added."""
        if self.goal is None or self.current is None or self.static_grid is None or self.local is None:
            return
        self.last_try = rospy.get_time()
        self.block_why = why
        goal, problem = self._goal_pose(self.goal)
        if problem:
            return
        merged = merge_local(self.static_grid, self.local, self.known, self.node_params.known_tolerance)
        held = self.held_replan
        if self.held_replan and self.planner is not None:  # keep the guard's distance from what it held for
            merged = mark_discs(merged, self.held_points.near(self.current[0], self.current[1]),
                                self.node_params.held_clearance, self.planner.footprint, self.current)
        self.held_replan = False
        t = time.monotonic()
        planner = Planner(merged, self.vehicle, self.p, self.heights, self.rollover)
        occupied = planner.check_pose(goal, "goal")
        # A moving vehicle drives on while the planner works: plan from where it will be on
        # its current path by then (short of the blockage), and keep the path up to there
        here = self.current
        prefix, start = self._replan_start(planner)
        start_msg = pose_stamped(*start, self.node_params.frame_id, rospy.Time.now())
        if occupied:
            return self._blocked(f"{why}; and the goal is blocked: {occupied}", start_msg)
        rospy.logwarn("planner: %s: replanning from (%.2f, %.2f)", why, start[0], start[1])
        self._set_status(PlannerStatus.PLANNING, why, start=start_msg, goal=self.goal)
        budget = self.node_params.replan_budget if not len(prefix) and abs(self.speed) < 0.2 and \
            self.member is None else None
        r = planner.plan(start, goal, budget, cancelled=self.cancel.is_set)
        if self.cancel.is_set():
            return
        took = time.monotonic() - t
        if self.member is None:  # a pessimistic running estimate (in lockstep the vehicle waits)
            self.replan_time = max(took, 0.5 * (self.replan_time + took))
        if not r.ok:
            return self._blocked(f"{why}; no other path: {r.reason}", start_msg, r)
        if not held:  # the path is blocked: a long way round waits for it to clear
            extra = path_length(prefix) + r.length - remaining_length(self.path_poses, here)
            if not self.detour.take(rospy.get_time(), extra):
                reason = f"{why}; waiting up to {self.detour.left(rospy.get_time()):.1f} s for it to clear: the way " \
                         f"round is {extra:.0f} m longer"
                rospy.logwarn("planner: BLOCKED: %s", reason)
                return self._set_status(PlannerStatus.BLOCKED, reason, start_msg, self.goal)
        if self._overtaken(prefix, start):
            # the vehicle drove past the replan's start while it was being planned: again,
            # from further ahead (the estimate of the planning time has grown)
            if self.jobs.empty():
                self.jobs.put(("replan", why))
            rospy.logwarn("planner: the vehicle passed the replan's start while planning (%.1f s): again", took)
            return
        self.detour.clear()
        self.replans += 1
        self.blocked_since = None
        self.held_since = None
        poses = np.concatenate([prefix, r.poses]) if len(prefix) else r.poses
        self._publish_path(path_msg(poses, self.node_params.frame_id, rospy.Time.now()))
        self.path_poses = poses
        self._set_status(PlannerStatus.FOUND, f"replanned ({why})" + (f"; {r.note}" if r.note else ""), start_msg,
                         self.goal, r)
        rospy.loginfo("planner: replanned around the obstacle in %.2f s: %.1f m, %d cusp(s)",
                      time.monotonic() - t, r.length, r.cusps)

    def _replan_start(self, planner: Planner):
        """(poses of the current path kept, the replan's start): see :func:`replan_start`."""
        return replan_start(self.path_poses, self.current, self.speed, self.replan_time + 0.5, planner.path_collides)

    def _overtaken(self, prefix: np.ndarray, start) -> bool:
        return overtaken(prefix, start, self.current)

    def _resume(self) -> None:
        """FOUND again: the path waited for is clear, the vehicle goes on along it."""
        self._set_status(PlannerStatus.FOUND, "the path cleared: going on", *self.last_found)

    def _blocked(self, reason: str, start: PoseStamped, r: Optional[PlanResult] = None) -> None:
        self.detour.waiting = False  # no way round to put off: retried every ~retry s
        if self.blocked_since is None:
            self.blocked_since = rospy.get_time()
            rospy.logwarn("planner: BLOCKED: %s (retrying every %.1f s; the vehicle stays stopped)", reason,
                          self.node_params.retry)
        self._set_status(PlannerStatus.BLOCKED, reason, start, self.goal, r)

    def _build(self, grid: Grid) -> None:
        self.static_grid = grid
        self.known = known_distance(grid)
        t = time.monotonic()
        self._set_status(PlannerStatus.IDLE, "preparing the map")
        with self.lock:
            self.planner = Planner(grid, self.vehicle, self.p, self.heights, self.rollover)
            if self.p.planner == "lattice":
                self.planner.lattice()
            else:
                self.planner.ompl()
        rospy.loginfo("planner: map of %d x %d cells of %.2f m ready in %.2f s", grid.width, grid.height,
                      grid.resolution, time.monotonic() - t)
        self._set_status(PlannerStatus.IDLE, "waiting for a goal")

    def _goal_pose(self, m: PoseStamped, what: str = "goal") -> Tuple[Optional[Tuple[float, float, float]], str]:
        frame = m.header.frame_id.lstrip("/")
        if frame and frame != self.node_params.frame_id:
            return None, f"{what} in frame '{m.header.frame_id}', expected '{self.node_params.frame_id}'"
        q = m.pose.orientation
        if not all(map(math.isfinite, (q.x, q.y, q.z, q.w))) or q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w < 1e-9:
            return None, f"{what} orientation is not a rotation"
        pose = (m.pose.position.x, m.pose.position.y, yaw_of(q))
        if not all(map(math.isfinite, pose)):
            return None, f"{what} {pose} is not finite"
        return pose, ""

    def _plan_goal(self, m: PoseStamped) -> None:
        goal, problem = self._goal_pose(m)
        if problem:
            return self._fail(problem, m)
        if self.planner is None:
            return self._set_status(PlannerStatus.IDLE, "goal received; waiting for a map", goal=m)
        if self.start is None:
            return self._set_status(PlannerStatus.IDLE, "goal received; waiting for the start pose "
                                                       "(localization/odom)", goal=m)
        sp = self.start.pose.pose
        start = (sp.position.x, sp.position.y, yaw_of(sp.orientation))
        start_msg = pose_stamped(*start, self.node_params.frame_id, self.start.header.stamp)
        self._set_status(PlannerStatus.PLANNING, "", start=start_msg, goal=m)
        with self.lock:
            r = self.planner.plan(start, goal, cancelled=self.cancel.is_set)
        if self.cancel.is_set():
            return  # a newer goal is waiting
        if not r.ok:
            return self._fail(r.reason, m, start_msg, r)
        self._publish_path(path_msg(r.poses, self.node_params.frame_id, rospy.Time.now()))
        self.path_poses = r.poses
        self.blocked_since = None
        self.detour.clear()
        self._set_status(PlannerStatus.FOUND, r.note, start_msg, m, r)
        rospy.loginfo("planner: %s path of %.1f m, %d cusp(s), cost %.1f; first solution in %.0f ms, %.2f s in all",
                      r.planner, r.length, r.cusps, r.cost, 1e3 * r.time_to_first, r.planning_time)

    def _publish_path(self, msg: PathMsg) -> None:
        """Advertised only once there is a path: a stack that drives a reference path (the
        figure eight) keeps a single publisher on planner/path."""
        if self.pub_path is None:  # latched: subscribers that connect later still get the path
            self.pub_path = rospy.Publisher("planner/path", PathMsg, queue_size=1, latch=True)
        publish(self.pub_path, msg)

    def _fail(self, reason: str, goal: PoseStamped, start: Optional[PoseStamped] = None,
              r: Optional[PlanResult] = None) -> None:
        rospy.logerr("planner: no path: %s", reason)
        self._set_status(PlannerStatus.FAILED, reason, start, goal, r)

    def _set_status(self, state: int, reason: str, start: Optional[PoseStamped] = None,
                    goal: Optional[PoseStamped] = None, r: Optional[PlanResult] = None) -> None:
        st = PlannerStatus()
        st.header.stamp = rospy.Time.now()
        st.header.frame_id = self.node_params.frame_id
        if self.map_warnings:  # every status says it while the map is likely misread
            reason = f"{reason} [map warning: {self.map_warnings[0]}]" if reason else \
                f"[map warning: {self.map_warnings[0]}]"
        st.state, st.reason = state, reason
        st.planner = self.p.planner
        if start is not None:
            st.start = start
        if goal is not None:
            st.goal = goal
        if r is not None:
            st.planning_time = r.planning_time
            st.time_to_first = r.time_to_first if math.isfinite(r.time_to_first) else 0.0
            st.cost = r.cost if math.isfinite(r.cost) else 0.0
            st.length = r.length if math.isfinite(r.length) else 0.0
            st.cusps = r.cusps if r.ok else 0
            st.expansions = r.expansions
        self.status = st
        if state == PlannerStatus.FOUND:
            self.last_found = (start, goal, r)
        publish(self.pub_status, st)

    # ----------------------------------------------------------------- service
    def _on_plan_service(self, req) -> PlanPathResponse:
        out = PlanPathResponse()
        if self.planner is None:
            out.message = "no map yet"
            return out
        start, problem = self._goal_pose(req.start, "start")
        goal, problem2 = self._goal_pose(req.goal)
        if problem or problem2:
            out.message = problem or problem2
            return out
        if req.planner and req.planner not in ("lattice", "ompl"):
            out.message = f"unknown planner '{req.planner}' (lattice, ompl)"
            return out
        if not (req.budget >= 0 and math.isfinite(req.budget)):
            out.message = f"budget {req.budget} s is not a duration"
            return out
        with self.lock:
            r = self.planner.plan(start, goal, req.budget or None, req.planner or None)
        out.success, out.message = r.ok, r.reason
        if r.ok:
            out.path = path_msg(r.poses, self.node_params.frame_id, rospy.Time.now())
            out.cost, out.length = r.cost, r.length
            out.time_to_first, out.planning_time = r.time_to_first, r.planning_time
        return out


def main() -> None:
    init_node("planner")  # joins lockstep when sim.launch lockstep:=true
    PlannerNode()
    rospy.spin()
