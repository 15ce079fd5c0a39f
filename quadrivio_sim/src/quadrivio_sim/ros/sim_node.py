"""ROS wiring of the simulator: owns ``/clock``, publishes layer-1 sensors and ground truth,
hosts the emulated PLC's TCP server.

Parameters (private, see ``config/sim.yaml`` for every key of the simulation itself):

* ``~real_time_factor`` (float, 1.0): sim seconds per wall second; 0 runs as fast as possible.
* ``~max_lag`` (float, 0.05): sim seconds the simulator may fall behind its real-time
  schedule and make up by stepping without waiting; a longer stall is dropped rather than
  raced through (see ``pacing.py``: a burst of sim time starves wall-clock nodes).
* ``~loop_hold`` (float, 0.1) and ``~loop_hold_budget`` (float, 0.5): at a factor other
  than 1, when the setpoints the PLC drives on are older than ``loop_hold`` sim seconds,
  serve the PLC link without stepping until a fresh one arrives, for at most
  ``loop_hold_budget`` wall seconds per stall (then time runs on and the PLC's watchdog
  brakes): the simulator slows to what the closed loop sustains instead of letting it act
  on stale data (``pacing.LoopHold``). At factor 1, and in lockstep, never.
* ``~stale_slowdown`` (dict, ``{localization/odom: 0.2, localization/predicted: 0.08,
  vehicle/setpoint/auto: 0.08}``)
  and ``~stale_slowdown_budget`` (float, 2.0): above factor 1 (or as fast as possible),
  while the PLC drives and the newest message of one of these stamped topics is older
  than its limit (sim s), run at real time, where the stack keeps its sim-time deadlines
  (the smoother's ``max_wait``), until every one is fresh again; at most the budget (wall
  s) per episode (``pacing.StaleSlowdown``). ``{}``: never.
* ``~stale_slowdown_fraction`` (float, 0) and ``~stale_slowdown_escalate`` (float, 0.1):
  an episode first runs at that fraction of the factor (never below real time), and at
  real time once it has lasted that many sim seconds; fraction 0: real time at once.
* ``~clock_every`` (int, 1): publish ``/clock`` every n physics steps.
* ``~steps_per_wake`` (int, 2): run n physics steps back to back, then wait for the pacing:
  each process wakes once per n steps instead of every step, which on a VM is most of the
  cost of a node (``bench_sensors``: a quarter less CPU with 2); the closed loop's answer
  to a step's readings may then be applied up to n - 1 steps (10 ms) later in sim time. 1:
  a wait before every step.
* ``~actuators_file`` (str): YAML of the PLC's low-level loops (``config/actuators.yaml``).
* ``~urdf_file`` (str, ""): vehicle URDF; empty generates it from ``/vehicle``.
* ``~debug_setpoints`` (bool, false): accept ``~debug/setpoint`` (quadrivio_plc/Setpoint),
  which puts the PLC in AUTO and bypasses the TCP link (tests only).
* ``~tf_mode`` (str, "ground_truth_frame"): ``map -> <gt_frame>`` TF from ground truth;
  ``base_link`` publishes ``map -> base_link`` (simulator alone, no localization); ``none``.
* ``~map_frame`` ("map"), ``~base_frame`` ("base_link"), ``~gt_frame`` ("base_link_ground_truth"),
  ``~imu_frame`` ("imu_link"), ``~mag_frame`` ("mag_link"): the frames of what it publishes
  (messages are built by the pure converters of ``converters.py``).
* ``~start_paused`` (bool, false).
* ``~script_file`` (str, ""): CSV/YAML of timed setpoints driving the PLC (open-loop runs).
* ``~run_until`` (float, 0): pause when sim time reaches it (0: never).

Publishes: ``/clock`` (rosgraph_msgs/Clock), ``ground_truth/odom`` (nav_msgs/Odometry),
``ground_truth/actors`` (quadrivio_sim/ActorArray: the scenario's actors and obstacles, at
``actors_rate``, when it has any), ``ground_truth/map_bodies`` (quadrivio_sim/ActorArray,
latched: the bodies built from the map's occupied cells, when there is a map),
``ground_truth/contacts`` (quadrivio_sim/Contact: each contact of the vehicle with a body
that is not the ground, as it begins),
``joint_states`` (sensor_msgs/JointState), ``/tf``, ``sim/gps`` (quadrivio_sim/RawGps),
``sim/imu`` (sensor_msgs/Imu), ``sim/mag`` (sensor_msgs/MagneticField),
``sim/scan/front|rear`` (sensor_msgs/LaserScan), ``sim/stereo/left|right/image_raw``
(sensor_msgs/Image), ``/diagnostics``.
Services: ``~pause``, ``~unpause``, ``~reset`` (std_srvs/Trigger), ``~step`` (quadrivio_sim/Step).
"""

from __future__ import annotations

import dataclasses
import os
import queue
import signal
import threading
import time
from dataclasses import dataclass
from typing import Callable, Dict, Optional

import rospy
import tf2_ros
from diagnostic_msgs.msg import DiagnosticStatus
from nav_msgs.msg import Odometry
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, Imu, JointState, LaserScan, MagneticField
from std_srvs.srv import Trigger, TriggerResponse

from quadrivio_config import ConfigError, from_mapping, load_yaml, param
from quadrivio_runtime.ros import diagnostics, init_node
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import (fatal, node_params, private_params, run_seed, site_params,
                                             split_params, vehicle_params, with_scenario)
from quadrivio_description.urdf import build_urdf
from quadrivio_plc.msg import Setpoint
from quadrivio_plc import protocol
from quadrivio_sim.msg import RawGps
from quadrivio_sim.srv import Step, StepResponse

from . import converters
from quadrivio_runtime.ros.clock import set_own_time, take_clock_ownership
from .lockstep_driver import LockstepDriver
from ..actuators import ActuatorParams
from ..paths import package_file
from ..pacing import LoopHold, Pacer, StaleSlowdown
from ..plc_emulator import DRIVING, EventThrottle, PlcServer, listening_exposure
from ..script import load_script
from ..simulator import SimParams, Simulator, with_scenario_world


@dataclass(frozen=True)
class NodeParams:
    real_time_factor: float = param(1.0, lo=0.0, hi=1000.0, doc="sim s per wall s; 0: as fast as possible")
    max_lag: float = param(0.05, lo=0.0, hi=10.0, unit="s",
                           doc="sim time a late simulator may make up by not waiting; a longer stall is dropped")
    loop_hold: float = param(0.1, lo=0.0, hi=10.0, unit="s",
                             doc="at a factor other than 1: wait for the PLC client when the setpoints the PLC "
                                 "drives on are older than this (sim s; below the PLC watchdog); 0: never")
    loop_hold_budget: float = param(0.5, lo=0.0, hi=60.0, unit="s",
                                    doc="wall seconds one such wait may last before time runs on (the watchdog brakes)")
    # 0.08 s, 4 periods of the 50 Hz topics: the slowdown reacts within a step, so a gap ends
    # below the 5 periods the contract allows. The follower's setpoints are watched here, not
    # by the loop hold: the PLC client repeats the last one for setpoint_timeout (0.25 s), so
    # the PLC's watchdog reference stays fresh while the follower is silent.
    stale_slowdown: Dict[str, float] = param({"localization/odom": 0.2, "localization/predicted": 0.08,
                                              "vehicle/setpoint/auto": 0.08}, lo=0.0,
                                             hi=60.0, unit="s",
                                             doc="above factor 1: run at real time while the newest message of one "
                                                 "of these stamped topics is older than this (sim s); {}: never")
    stale_slowdown_budget: float = param(2.0, lo=0.0, hi=600.0, unit="s",
                                         doc="wall seconds one such slowdown may last (a node that died)")
    # 0 by default: at 0.7 the figure eight asked for 5 achieves 4.0-4.2 instead of 2.7-3.2,
    # but in a 10-minute run /localization/predicted and the setpoints went 0.19-0.22 s
    # without a message (5 periods allowed): a wait for a core of X wall ms is X times the
    # factor in sim time, and the fraction keeps the factor high while the loop waits.
    stale_slowdown_fraction: float = param(0.0, lo=0.0, hi=0.99,
                                           doc="a slowdown first runs at this fraction of the factor (not below "
                                               "real time): faster runs, staler data; 0: at real time at once")
    stale_slowdown_escalate: float = param(0.1, lo=0.0, hi=60.0, unit="s",
                                           doc="sim seconds a slowdown runs at that fraction before real time")
    clock_every: int = param(1, lo=1, hi=1000, doc="publish /clock every n physics steps")
    # 2: every process wakes half as often (the steps' messages arrive together and rospy
    # reads them in one go), and on this VM a wake-up from idle is most of a node's cost:
    # bench_sensors 0.154-0.165 -> 0.116-0.125 of a core (k 4: 0.096-0.102), alternated in
    # one spell. The price: the loop's answer to a step may land one step later (10 ms).
    steps_per_wake: int = param(2, lo=1, hi=100, doc="physics steps run back to back before the pacing waits "
                                                     "(the factor holds on average; the loop's answer may come "
                                                     "up to n-1 steps later in sim time)")
    actuators_file: str = param("", doc="YAML of the low-level loops; empty: the package's config/actuators.yaml")
    urdf_file: str = param("", doc="vehicle URDF; empty: generated from the vehicle parameters")
    debug_setpoints: bool = param(False, doc="accept ~debug/setpoint (tests)")
    tf_mode: str = param("ground_truth_frame", choices=("ground_truth_frame", "base_link", "none"))
    map_frame: str = param("map")
    base_frame: str = param("base_link")
    gt_frame: str = param("base_link_ground_truth")
    imu_frame: str = param("imu_link", doc="frame of /sim/imu (the IMU's link in the URDF)")
    mag_frame: str = param("mag_link", doc="frame of /sim/mag (the magnetometer's link in the URDF)")
    start_paused: bool = param(False)
    script_file: str = param("", doc="CSV/YAML of timed setpoints driving the PLC in AUTO (open-loop runs)")
    run_until: float = param(0.0, lo=0.0, hi=1e7, unit="s", doc="pause when sim time reaches this (0: never)")


class SimNode:
    def __init__(self) -> None:
        raw = private_params()
        node_raw, sim_raw = split_params(raw, NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, node_raw)
        self.sim_params: SimParams = with_scenario(node_params(SimParams, sim_raw), "sim")
        try:  # the scenario's actors and map (the map_server's too: the world's obstacles), DEM
            self.sim_params = with_scenario_world(
                self.sim_params, rospy.get_param("/scenario/actors", None), rospy.get_param("/scenario/map", None),
                rospy.get_param("/scenario/source", ""), "/scenario")
        except ConfigError as exc:
            fatal(f"bad scenario parameter: {exc}")
        if rospy.has_param("/run/seed") or rospy.has_param("/scenario/seed"):
            self.sim_params = dataclasses.replace(self.sim_params, seed=run_seed())
        self.vehicle = vehicle_params()
        actuators_file = self.node_params.actuators_file or package_file("config", "actuators.yaml")
        try:
            actuators = from_mapping(ActuatorParams, load_yaml(actuators_file), actuators_file)
        except ConfigError as exc:
            fatal(f"bad actuator file: {exc}")
        urdf = self._urdf_text()
        try:
            self.sim = Simulator(self.sim_params, self.vehicle, actuators, urdf, site_params())
        except ConfigError as exc:
            fatal(f"cannot build the simulation: {exc}")
        for k, line in enumerate(self.sim.map_report):
            (rospy.loginfo if k == 0 else rospy.logwarn)("simulator: %s", line)
        if self.node_params.script_file:
            try:
                self.sim.script = load_script(self.node_params.script_file)
            except ConfigError as exc:
                fatal(str(exc))
            rospy.loginfo("driving the PLC from %s (%.1f s of setpoints)", self.node_params.script_file, self.sim.script.end)
        plc = self.sim_params.plc
        try:
            key = protocol.ensure_key(plc.key_file)
        except (protocol.KeyFileError, OSError) as exc:
            fatal(f"the emulated PLC has no usable key: {exc}")
        for warning in protocol.key_warnings(plc.key_file, key):
            rospy.logwarn(warning)
        try:
            self.server = PlcServer(self.sim.plc, plc.host, plc.port, lambda: self.sim.t, self._log, key=key)
        except OSError as exc:
            fatal(str(exc))
        rospy.loginfo("emulated PLC listening on %s:%d", *self.server.address)
        self.event_throttle = EventThrottle()  # PLC events: a few lines a second per kind, whatever arrives
        exposure = listening_exposure(self.server.address[0])
        if exposure:
            rospy.logwarn("the emulated PLC listens on %s (plc.host %s): %s; only the key stands between it and "
                          "anyone who can reach this port", self.server.address[0], plc.host, exposure)

        self.lock = threading.Lock()
        self.requests: "queue.Queue[Callable[[], None]]" = queue.Queue()
        self.paused = self.node_params.start_paused
        self.rtf = self.node_params.real_time_factor
        self.debug_sp: Optional[Setpoint] = None
        self.behind_warned = 0.0
        self.pacer = Pacer(self.rtf, self.node_params.max_lag)
        # At factor 1 the simulator is the world, which does not wait (pacing.LoopHold)
        self.hold = LoopHold(self.node_params.loop_hold if self.rtf != 1.0 else 0.0, self.node_params.loop_hold_budget)
        self.stopped = False
        self.stop_event = threading.Event()
        self.lockstep: Optional[LockstepDriver] = None
        if rospy.get_param("/lockstep/enabled", False):
            if self.node_params.clock_every != 1:
                fatal(f"lockstep needs ~clock_every = 1 (a round per /clock tick), not {self.node_params.clock_every}")
            self.lockstep = LockstepDriver(self.server, lambda: self.stop_event.is_set() or rospy.is_shutdown())
        # Above factor 1 the stack's sim-time deadlines shrink in wall time (pacing.StaleSlowdown);
        # lockstep waits for the loop anyway
        fast = self.lockstep is None and (self.rtf == 0.0 or self.rtf > 1.0)
        self.slowdown = StaleSlowdown(self.node_params.stale_slowdown if fast else {}, self.node_params.stale_slowdown_budget,
                                      self.node_params.stale_slowdown_fraction, self.node_params.stale_slowdown_escalate)
        self.watched_stamped: Dict[tuple, bool] = {}  # (topic, md5sum) -> whether a Header comes first
        for topic in self.slowdown.max_age:
            # Only the header's stamp is read, from the serialised message (no deserialisation)
            rospy.Subscriber(topic, rospy.AnyMsg, self._on_watched, callback_args=topic, queue_size=1)

        # Written in this thread while each subscriber keeps up, not by a writer thread per
        # subscriber (a thread wake-up per message and subscriber: see
        # quadrivio_runtime.ros.direct); queued for a subscriber only while it is behind.
        self.pub_clock = direct_publisher("/clock", Clock, queue_size=1000)
        self.pub_gt = direct_publisher("ground_truth/odom", Odometry, queue_size=50)
        self.pub_joints = direct_publisher("joint_states", JointState, queue_size=10)
        from quadrivio_sim.msg import ActorArray, Contact

        self.pub_actors = direct_publisher("ground_truth/actors", ActorArray, queue_size=10)
        self.pub_contacts = rospy.Publisher("ground_truth/contacts", Contact, queue_size=100)
        if self.sim.map_blocks:  # what the metrics judge clearances against, as the simulator built it
            self.pub_map_bodies = rospy.Publisher("ground_truth/map_bodies", ActorArray, queue_size=1, latch=True)
            self.pub_map_bodies.publish(converters.map_bodies(self.sim.map_blocks,
                                                              self.sim_params.map.obstacle_height,
                                                              self.node_params.map_frame, self.sim.t))
        self.pub_gps = direct_publisher("sim/gps", RawGps, queue_size=50)
        self.pub_imu = direct_publisher("sim/imu", Imu, queue_size=200)
        self.pub_mag = direct_publisher("sim/mag", MagneticField, queue_size=100)
        self.pub_scan = {f: direct_publisher(f"sim/scan/{f.replace('laser_', '')}", LaserScan, queue_size=10)
                         for f in self.sim_params.sensors.lasers.frames}
        self.pub_image = {f: rospy.Publisher(f"sim/stereo/{f.replace('camera_', '')}/image_raw", Image, queue_size=2)
                          for f in self.sim_params.sensors.cameras.frames} if self.sim.cameras else {}
        self.pub_info = {f: rospy.Publisher(f"sim/stereo/{f.replace('camera_', '')}/camera_info", CameraInfo,
                                            queue_size=2) for f in self.pub_image}
        self.baseline = self._stereo_baseline()
        self.tf = tf2_ros.TransformBroadcaster() if self.node_params.tf_mode != "none" else None
        self.frames = converters.Frames(map=self.node_params.map_frame, base=self.node_params.base_frame,
                               ground_truth_child=(self.node_params.gt_frame if self.node_params.tf_mode == "ground_truth_frame"
                                                   else self.node_params.base_frame),
                               imu=self.node_params.imu_frame, mag=self.node_params.mag_frame)

        rospy.Service("~pause", Trigger, lambda _: self._set_paused(True))
        rospy.Service("~unpause", Trigger, lambda _: self._set_paused(False))
        rospy.Service("~reset", Trigger, self._srv_reset)
        rospy.Service("~step", Step, self._srv_step)
        if self.node_params.debug_setpoints:
            rospy.Subscriber("~debug/setpoint", Setpoint, self._on_debug_setpoint, queue_size=10)
            rospy.logwarn("debug setpoints enabled: ~debug/setpoint drives the PLC in AUTO, bypassing the TCP link")

        self.diag = diagnostics.updater()
        self.diag.setHardwareID("quadrivio_sim")
        self.diag.add("simulator", self._diag_sim)
        self.diag.add("emulated PLC", self._diag_plc)
        self.wall_rtf = None  # achieved factor of the last wall window while running (None: none yet)

    # ---------------------------------------------------------------- set-up
    def _urdf_text(self) -> str:
        if not self.node_params.urdf_file:
            return build_urdf(self.vehicle)
        path = self.node_params.urdf_file
        if not os.path.isfile(path):
            fatal(f"~urdf_file {path}: file not found")
        with open(path, "r", encoding="utf-8") as fh:
            text = fh.read()
        import xml.etree.ElementTree as ET

        try:
            root = ET.fromstring(text)
        except ET.ParseError as exc:
            fatal(f"~urdf_file {path}: malformed XML: {exc}")
        if root.tag != "robot":
            fatal(f"~urdf_file {path}: the root element is <{root.tag}>, not <robot>")
        return text

    def _log(self, level: str, text: str) -> None:
        {"info": rospy.loginfo, "warn": rospy.logwarn, "error": rospy.logerr}.get(level, rospy.loginfo)(text)

    # -------------------------------------------------------------- services
    def _run_in_loop(self, fn: Callable[[], object], timeout: float = 30.0):
        """Run ``fn`` in the simulation thread between two steps and return its result."""
        done = threading.Event()
        box = {}

        def job() -> None:
            # A failing job must fail its service call, never the simulation loop.
            try:
                box["result"] = fn()
            except Exception as exc:  # noqa: BLE001
                box["error"] = f"{type(exc).__name__}: {exc}"
                rospy.logerr("simulator request failed: %s", box["error"])
            finally:
                done.set()

        self.requests.put(job)
        if not done.wait(timeout):
            raise rospy.ServiceException("the simulation loop did not answer")
        if "error" in box:
            raise rospy.ServiceException(box["error"])
        return box["result"]

    def _set_paused(self, paused: bool) -> TriggerResponse:
        def job():
            self.paused = paused
            self._anchor()
        self._run_in_loop(job)
        return TriggerResponse(True, f"{'paused' if paused else 'running'} at t = {self.sim.t:.3f} s")

    def _srv_reset(self, _req) -> TriggerResponse:
        def job():
            self.sim.reset()
            self.stopped = False
            self._anchor()
            rospy.logwarn("simulation reset to t = 0 (the clock jumps back)")
        self._run_in_loop(job)
        return TriggerResponse(True, "reset to t = 0")

    def _srv_step(self, req) -> StepResponse:
        if not self.paused:
            raise rospy.ServiceException("~step needs a paused simulator; call ~pause first")

        def job():
            for _ in range(req.steps):
                self._step_once()
            return self.sim.t
        return StepResponse(self._run_in_loop(job, timeout=60.0 + req.steps * 0.01))

    def _on_watched(self, msg: rospy.AnyMsg, topic: str) -> None:
        header = getattr(msg, "_connection_header", None) or {}
        kind = (topic, header.get("md5sum"))
        stamped = self.watched_stamped.get(kind)
        if stamped is None:  # once per topic and type, not per message (the definition is kilobytes)
            stamped = self.watched_stamped[kind] = converters.starts_with_header(header.get("message_definition", ""))
        if not stamped:
            rospy.logerr_throttle(10.0, "~stale_slowdown: %s is %s, not a stamped message (a Header first): "
                                        "not watched", topic, header.get("type", "of an unknown type"))
            return
        try:
            secs, nsecs = converters.header_stamp(msg._buff)
        except ValueError as exc:
            rospy.logerr_throttle(10.0, "~stale_slowdown: %s on %s: not watched", exc, topic)
            return
        self.slowdown.seen(topic, secs + 1e-9 * nsecs)

    def _on_debug_setpoint(self, msg: Setpoint) -> None:
        with self.lock:
            self.debug_sp = msg

    # ------------------------------------------------------------------ loop
    def _anchor(self) -> None:
        self.pacer.anchor(self.sim.t, time.monotonic())

    def spin(self, stop: threading.Event) -> None:
        self.stop_event = stop
        if self.lockstep is not None and not self.lockstep.arm():
            self.server.close()
            self.sim.close()
            return
        # No /clock before the first step: time 0 means "no time yet" to every ROS node.
        if self.sim.t > 0.0:
            self._publish_clock()
        self._anchor()
        self.window = (time.monotonic(), self.sim.t, self.paused)
        while not stop.is_set() and not rospy.is_shutdown():
            while not self.requests.empty():
                self.requests.get_nowait()()
            if self.paused:
                self.server.poll(0.02)
                self._drain_plc_events()
                self._report_window()  # a paused simulator still says so, and what its PLC sees
                continue
            if self.lockstep is None and self._loop_late():
                self.hold.wait(self.sim.t, lambda: self.sim.plc.fresh_since, self._driving, self.server.poll,
                               time.monotonic)
                self._drain_plc_events()
                self._anchor()  # the wait is not made up by a burst of steps
                continue
            self._step_once()
            if self.slowdown.enabled:
                self._pace_for_the_loop()
            if self.node_params.run_until and self.sim.t >= self.node_params.run_until - 1e-9 and not self.stopped:
                rospy.loginfo("reached ~run_until = %.3f s: pausing", self.node_params.run_until)
                self.paused = self.stopped = True
            if self.sim.steps % self.node_params.steps_per_wake:
                self.server.poll(0.0)  # the next step at once: one wake-up per batch of steps
                continue
            drops = self.pacer.drops
            self._poll_until(time.monotonic() + self.pacer.wait(self.sim.t, time.monotonic()))
            if self.pacer.drops != drops:
                now = time.monotonic()
                if now - self.behind_warned > 10.0:
                    rospy.logwarn("simulator behind real_time_factor %.2f by more than ~max_lag %.3f s: "
                                  "%.3f s of sim time dropped so far", self.rtf, self.node_params.max_lag,
                                  self.pacer.dropped)
                    self.behind_warned = now
            self._drain_plc_events()
            self._report_window()
        self.server.close()
        self.sim.close()

    def _report_window(self) -> None:
        """/diagnostics once a wall window (1 s, or the updater's period if longer), and at once
        when the simulator pauses or resumes. Every window is reported: diagnostic_updater's
        update() waits for a period of sim time, which a window that fell behind at factor 1
        had not advanced (a 0.6 s stall went unreported, the next window's 1.0 published
        instead) and a paused simulator never advances. A window is all running or all
        paused: the paused wall seconds are not read as a simulator behind its factor."""
        now = time.monotonic()
        t0, s0, was_paused = self.window
        if self.paused == was_paused and now - t0 < max(1.0, self.diag.period):
            return
        if self.paused != was_paused:
            self.wall_rtf = None  # until a window of the new state is measured
        elif not self.paused and self.sim.t >= s0:  # not across a ~reset
            self.wall_rtf = (self.sim.t - s0) / (now - t0)
        self.window = (now, self.sim.t, self.paused)
        self.diag.force_update()

    def _pace_for_the_loop(self) -> None:
        f = self.slowdown.factor(self.rtf, self.sim.t, self._driving(), time.monotonic())
        # The next step stays paced across the change (anchoring it at now, after the step,
        # ran it at once: one step unpaced at every change; see Pacer.set_factor)
        self.pacer.set_factor(f, self.sim.t, time.monotonic())

    def _driving(self) -> bool:
        return self.server.connected and self.sim.plc.mode in DRIVING

    def _loop_late(self) -> bool:
        # Every step: at factor 1 (the hold off) read nothing else
        return self.hold.enabled and self.hold.due(self.sim.t, self.sim.plc.fresh_since, self._driving())

    def _poll_until(self, deadline: float) -> None:
        """Serve the PLC port until the wall-clock ``deadline`` of the next step. A frame
        (or a flood of them) ends a select early; the step must still wait its turn, or a
        busy socket would run the simulation ahead of its real-time factor."""
        while True:
            self.server.poll(max(0.0, deadline - time.monotonic()))
            if time.monotonic() >= deadline:
                return

    WARN_EVENTS = ("stop", "refused", "clamped")

    def _drain_plc_events(self) -> None:
        for kind, text in self.sim.plc.pop_events():
            line = self.event_throttle.admit(kind, text)
            if line is not None:
                (rospy.logwarn if kind in self.WARN_EVENTS else rospy.loginfo)("PLC: %s", line)

    def _step_once(self) -> None:
        with self.lock:
            sp, self.debug_sp = self.debug_sp, None
        if sp is not None:
            self.sim.plc.force_auto(self.sim.t)
            self.sim.plc.setpoint(protocol.SOURCE_AUTO, sp.speed, sp.handlebar, sp.brake)
        client = self.server.connected
        for name, sample in self.sim.step():
            self._publish(name, sample)
            # Answer PLC frames between publications too, not only once per step: a
            # frame arriving now waits one publication (~50 us), not the whole step.
            if client:
                self.server.poll(0.0)
        if self.sim.steps % self.node_params.clock_every == 0:
            self._publish_clock()
            if self.lockstep is not None:  # the loop consumes this tick before the next step
                self.lockstep.settle(self.sim.t)

    def _publish_clock(self) -> None:
        stamp = converters.stamp(self.sim.t)
        set_own_time(stamp)
        self.pub_clock.publish(Clock(clock=stamp))

    # ------------------------------------------------------------ publishing
    def _publish(self, name: str, s) -> None:
        f = self.frames
        if name == "plc_state":
            self.server.send_state(s)
        elif name == "ground_truth":
            odom, tf = converters.ground_truth(s, f)
            self.pub_gt.publish(odom)
            if self.tf is not None:
                self.tf.sendTransform(tf)
        elif name == "imu":
            self.pub_imu.publish(converters.imu(s, f))
        elif name == "gps":
            self.pub_gps.publish(converters.gps(s, f))
        elif name == "mag":
            self.pub_mag.publish(converters.mag(s, f))
        elif name == "scan":
            self.pub_scan[s.frame].publish(converters.scan(s))
        elif name == "joint_states":
            self.pub_joints.publish(converters.joints(s))
        elif name == "actors":
            self.pub_actors.publish(converters.actors(s, f.map, self.sim.t))
        elif name == "contact":
            self.pub_contacts.publish(converters.contact(s, f.map))
            rospy.logwarn("contact: the vehicle touched %s (%s) at %.2f m/s, t = %.2f s", s.body, s.kind, s.speed,
                          s.stamp)
        elif name == "image":
            img, info = converters.image(s, self.baseline, s.frame == self.sim_params.sensors.cameras.frames[-1])
            self.pub_image[s.frame].publish(img)
            self.pub_info[s.frame].publish(info)

    def _stereo_baseline(self) -> float:
        frames = self.sim_params.sensors.cameras.frames
        if len(frames) != 2 or not all(f in self.sim.world.frames for f in frames):
            return 0.0
        (a, _), (b, _) = (self.sim.world.frames[f] for f in frames)
        return float(sum((x - y) ** 2 for x, y in zip(a, b)) ** 0.5)

    # ----------------------------------------------------------- diagnostics
    def _diag_sim(self, stat):
        if self.paused:
            stat.summary(DiagnosticStatus.OK, f"paused{' (reached ~run_until)' if self.stopped else ''}")
        else:
            stat.summary(DiagnosticStatus.OK, "running")
        achieved = None if self.paused else self.wall_rtf  # of the last window; a paused simulator has none
        if achieved is not None and self.rtf > 0 and achieved < 0.9 * self.rtf:
            stat.summary(DiagnosticStatus.WARN, f"behind: real-time factor {achieved:.2f} < {self.rtf:.2f}")
        stat.add("sim time [s]", f"{self.sim.t:.3f}")
        stat.add("requested real-time factor", f"{self.rtf:g}")
        if achieved is not None:
            stat.add("achieved real-time factor", f"{achieved:.2f}")
        stat.add("sim time dropped behind schedule [s]", f"{self.pacer.dropped:.3f} in {self.pacer.drops} stalls")
        if self.hold.enabled:
            stat.add("waits for the PLC client's setpoints", f"{self.hold.holds} ({self.hold.held:.2f} wall s), "
                     f"{self.hold.given_up} given up (the watchdog's to brake)")
        sd = self.slowdown
        if sd.enabled:
            stat.add("slowed down for a stale stream", ", ".join(f"{k} {v}" for k, v in sd.episodes.items()) +
                     f" ({sd.slow_wall:.2f} wall s), {sd.escalated} on to real time, {sd.given_up} given up")
        ls = self.lockstep
        if ls is not None:
            if ls.left or ls.errors:
                stat.summary(DiagnosticStatus.WARN, f"lockstep broken: {ls.errors} lost waits, members gone: "
                                                    f"{' '.join(ls.left) or 'none'} (this run will not repeat exactly)")
            stat.add("lockstep members", " ".join(ls.coord.members))
            stat.add("lockstep rounds per step", f"{ls.rounds / max(ls.steps, 1):.2f}")
            stat.add("lockstep waits that gave up", str(ls.errors))
        return stat

    def _diag_plc(self, stat):
        plc = self.sim.plc
        level = DiagnosticStatus.OK if self.server.connected else DiagnosticStatus.WARN
        stat.summary(level, f"{'client ' + self.server.peer if self.server.connected else 'no client'}, "
                            f"mode {protocol.mode_name(plc.mode)}")
        st = self.server.stats
        stat.add("faults", str(plc.faults))
        stat.add("sessions", str(st.sessions))
        stat.add("frames received", str(st.frames))
        stat.add("bad frames", str(sum(st.bad_frames.values())))
        stat.add("bad frames by reason", str(st.bad_frames))
        stat.add("stale frames (sequence did not advance)", str(st.stale_frames))
        stat.add("frames sent", str(self.server.frames_sent))
        stat.add("connections refused", str(st.refused))
        stat.add("authentication failures", str(st.auth_failures))
        stat.add("watchdog trips", str(plc.watchdog_trips))
        stat.add("link losses", str(plc.link_losses))
        return stat


def main() -> None:
    # Signals only set a flag that the loop checks between steps: a KeyboardInterrupt
    # raised anywhere (inside rospy's logging, say) can leave a lock held and the node
    # stuck until roslaunch escalates to SIGTERM 15 s later.
    init_node("simulator", disable_signals=True, lockstep=False)  # it drives lockstep's rounds
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda signum, _frame: stop.set())
    node = SimNode()
    if rospy.get_param("/use_sim_time", False):
        take_clock_ownership()
    node.spin(stop)
    rospy.signal_shutdown("simulator stopped")
