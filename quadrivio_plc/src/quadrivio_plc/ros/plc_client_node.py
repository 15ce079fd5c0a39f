"""PLCClient: the ROS node that talks to the real or emulated PLC (see ``PROTOCOL.md``).

Parameters (private): ``~host`` (str, 127.0.0.1), ``~port`` (int, 5020), ``~send_rate``
(Hz, 50), ``~setpoint_timeout`` (s, 0.25), ``~stop_brake`` (0.5), ``~connect_timeout``
(s, 1), ``~reconnect_min`` / ``~reconnect_max`` (s, 0.1 / 5), ``~mode_timeout`` (s, 1),
``~frame_id`` (base_link), ``~initial_mode`` (str, "": request this mode once connected),
``~plc_clock`` (auto | ros | estimate: whether ``plc_time`` is ROS time, as the emulated
PLC's sim time is; auto: ros under /use_sim_time).

``~key_file`` (str, "": $ROS_HOME/quadrivio_plc.key, the PLC's shared session key).
``~initial_mode`` is requested again after ROS time moves back (the simulator's ``~reset``
restarts its PLC in SAFE).

Subscribes: ``vehicle/setpoint/auto``, ``vehicle/setpoint/manual`` (quadrivio_plc/Setpoint),
``safety/interlock`` (quadrivio_plc/Interlock: while one is active, driving modes are
refused and a driving PLC is sent to SAFE at once).
Publishes: ``vehicle/state`` (quadrivio_plc/VehicleState) for every PLC state frame, and
at 10 Hz with FAULT_LINK, NaN measurements and mode SAFE (HALT if it was in HALT), never a
driving mode, while there is no session;
``/diagnostics`` (link health).
Services: ``~set_mode`` (quadrivio_plc/SetMode); ``~acknowledge`` (std_srvs/Trigger): the
reset after a stop for a fault (WATCHDOG, LINK), which the PLC takes at a verified standstill
only and needs before a driving mode is entered again (PROTOCOL.md, Re-entry).
"""

from __future__ import annotations

import math
import threading
import traceback
from dataclasses import dataclass
from typing import Dict

import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from std_srvs.srv import Trigger, TriggerResponse

from quadrivio_config import param
from quadrivio_runtime.ros import diagnostics, init_node, lockstep
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import node_params, private_params, split_params
from quadrivio_runtime.ros.timer import guarded_timer, on_clock_jump, publish

from .. import protocol
from ..client import Multiplexer, PlcClientParams, PlcClock, PlcLink, mode_without_session
from ..msg import Interlock, Setpoint, VehicleState
from ..srv import SetMode, SetModeResponse


@dataclass(frozen=True)
class NodeParams:
    initial_mode: str = param("", choices=("", "HALT", "SAFE", "MANUAL", "ASSISTED", "AUTO"),
                              doc="mode to request once connected (empty: none)")


DRIVING = (protocol.MODE_MANUAL, protocol.MODE_ASSISTED, protocol.MODE_AUTO)
LATCHED = protocol.FAULT_WATCHDOG | protocol.FAULT_LINK  # acknowledged (~acknowledge) before a driving mode


class PlcClientNode:
    def __init__(self) -> None:
        mine, rest = split_params(private_params(), NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, mine)
        self.p: PlcClientParams = node_params(PlcClientParams, rest)
        self.mux = Multiplexer(self.p.setpoint_timeout, self.p.stop_brake)
        self.mode = -1  # unknown until the first state frame
        self.faults = 0
        self.rejected: Dict[int, int] = {}
        self.bad_input = 0
        self.interlocks: Dict[str, str] = {}  # active interlocks: source -> reason
        self.initial_sent = False
        self.link_down_published = -1e9
        shared = self.p.plc_clock == "ros" or (self.p.plc_clock == "auto" and bool(rospy.get_param("/use_sim_time", False)))
        self.clock = PlcClock(shared=shared)
        self.pub_state = direct_publisher("vehicle/state", VehicleState, queue_size=50)
        on_state, on_ack = self._on_state, self._on_ack
        self.lockstep = lockstep.member()
        if self.lockstep is not None:
            # STATE frames are handled in the simulator's rounds, like messages; ACKs at once
            ls = self.lockstep
            on_state = lambda s: ls.frame(lockstep.STATE_TOPIC, lambda: self._on_state(s))  # noqa: E731
            on_ack = lambda a: ls.frame(lockstep.ACK_TOPIC, lambda: self._on_ack(a))  # noqa: E731
        self.link = PlcLink(self.p.host, self.p.port, connect_timeout=self.p.connect_timeout,
                            reconnect_min=self.p.reconnect_min, reconnect_max=self.p.reconnect_max,
                            on_state=on_state, on_ack=on_ack, on_event=self._log,
                            key_file=self.p.key_file)
        if self.lockstep is not None:
            self.lockstep.link(lambda: self.link.connected, lambda: self.link.stats.frames_sent)
        self.setpoint_subs = {
            protocol.SOURCE_AUTO: rospy.Subscriber("vehicle/setpoint/auto", Setpoint, self._on_setpoint, protocol.SOURCE_AUTO,
                                            queue_size=10),
            protocol.SOURCE_MANUAL: rospy.Subscriber("vehicle/setpoint/manual", Setpoint, self._on_setpoint,
                                              protocol.SOURCE_MANUAL, queue_size=10)}
        rospy.Subscriber("safety/interlock", Interlock, self._on_interlock, queue_size=20)
        rospy.Service("~set_mode", SetMode, self._srv_set_mode)
        rospy.Service("~acknowledge", Trigger, self._srv_acknowledge)
        self.diag = diagnostics.updater()
        self.diag.setHardwareID(f"PLC {self.p.host}:{self.p.port}")
        self.diag.add("PLC link", self._diagnose)
        self.io = threading.Thread(target=self._io_loop, name="plc_io", daemon=True)
        self.io.start()
        guarded_timer(1.0 / self.p.send_rate, self._tick, "setpoint cycle")
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        on_clock_jump(self._on_clock_jump)

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        # Setpoints stamped before the jump are stale (the multiplexer sends stops); the
        # simulator's PLC restarted in SAFE, so the initial mode is requested again.
        self.mux = Multiplexer(self.p.setpoint_timeout, self.p.stop_brake)
        self.initial_sent = False
        self.link_down_published = -1e9
        self.clock.reset()

    # -------------------------------------------------------------- link I/O
    def _io_loop(self) -> None:
        while not rospy.core.is_shutdown_requested():
            try:
                self.link.poll(0.05)
            except Exception:  # noqa: BLE001 - the link thread must outlive one bad frame or callback
                rospy.logerr_throttle(5.0, "PLC link I/O failed (continuing):\n%s", traceback.format_exc())
        self.link.close()

    def _log(self, level: str, text: str) -> None:
        if level == "info":
            rospy.loginfo(text)
        elif level == "notice":
            rospy.logwarn(text)
        else:
            rospy.logwarn_throttle(2.0, text)

    def _on_state(self, s: protocol.State) -> None:
        first = self.mode < 0
        self.mode, self.faults = s.mode, s.faults
        if self.interlocks and s.mode in DRIVING:
            self._stop_for_interlock()
        m = VehicleState()
        # when the PLC measured it: a frame read late (this process descheduled or stopped,
        # a backlog in the socket) is not a fresh measurement
        mismatch = self.clock.mismatch
        m.header.stamp = rospy.Time.from_sec(self.clock.stamp(s.plc_time, rospy.get_time()))
        if self.clock.mismatch > mismatch:
            rospy.logwarn_throttle(10.0, "~plc_clock: the PLC's clock is %.1f s off ROS time, so it is not ROS "
                                   "time: states are stamped on the estimated offset (%d so far)",
                                   -self.clock.offset, self.clock.mismatch)
        m.header.frame_id = self.p.frame_id
        m.wheel_speed, m.handlebar, m.throttle, m.brake = s.wheel_speed, s.handlebar, s.throttle, s.brake
        m.mode, m.faults, m.plc_time = s.mode, s.faults, s.plc_time
        m.setpoint_speed, m.setpoint_handlebar = s.setpoint_speed, s.setpoint_handlebar
        if not publish(self.pub_state, m):
            return
        if first:
            rospy.loginfo("PLC in mode %s", protocol.mode_name(s.mode))
        # Not before this node's clock runs (sim time 0: no /clock yet): its 50 Hz frames come
        # from a sim-time timer, so a driving mode asked for then has the watchdog brake and
        # the session time out before the first frame (a fresh clone's plan_and_drive.test)
        if self.node_params.initial_mode and not self.initial_sent and rospy.get_time() > 0.0:
            self.initial_sent = True
            self._in_background(self._request_mode, protocol.MODE_BY_NAME[self.node_params.initial_mode])

    def _on_ack(self, ack: protocol.Ack) -> None:
        self.mode = ack.mode
        if ack.acked_type == protocol.Setpoint.TYPE and ack.status not in (protocol.OK,):
            self.rejected[ack.status] = self.rejected.get(ack.status, 0) + 1
            rospy.logwarn_throttle(2.0, "PLC: setpoint %s (mode %s)", protocol.STATUS_NAMES.get(ack.status, ack.status),
                                   protocol.mode_name(ack.mode))

    # ------------------------------------------------------------- setpoints
    def _on_setpoint(self, msg: Setpoint, source: int) -> None:
        if not all(math.isfinite(v) for v in (msg.speed, msg.handlebar, msg.brake)):
            self.bad_input += 1
            rospy.logwarn_throttle(2.0, "dropped a %s setpoint with a value that is not a finite number "
                                   "(speed %r, handlebar %r, brake %r)", protocol.SOURCE_NAMES[source], msg.speed,
                                   msg.handlebar, msg.brake)
            return
        now = rospy.get_time()
        if self.interlocks:
            return  # stops only (see _tick)
        self.mux.update(source, now, msg.speed, msg.handlebar, msg.brake)
        mode = self.mode  # read once: the I/O thread changes it
        if self.mux.accepts(mode, source):  # forward at once: no extra latency
            for frame in self.mux.frames(mode, now):
                if frame.source == source:  # type: ignore[union-attr]
                    self.link.send(frame)

    def _tick(self, _event) -> None:
        if not self.link.connected:
            self._publish_link_down()
            return
        mode = self.mode  # read once: the I/O thread changes it
        now = rospy.get_time()
        if self.interlocks:
            self.mux.latest = {src: None for src in self.mux.latest}  # stops, whatever arrives
        for frame in self.mux.frames(mode, now):
            self.link.send(frame)
        if mode in DRIVING:
            for source, stale in self.mux.stale.items():
                if stale and self.mux.accepts(mode, source):
                    # how many publishers it is connected to: 0 while the master lists one is a
                    # subscription that never connected (the start-up race quadrivio_description
                    # .ros.rospy_mends mends)
                    sub = self.setpoint_subs[source]
                    rospy.logwarn_throttle(5.0, "no fresh %s setpoint in mode %s, %s: sending a stop "
                                           "(connected to %d publishers of %s)", protocol.SOURCE_NAMES[source],
                                           protocol.mode_name(mode), self.mux.why_stale(source, now),
                                           sub.get_num_connections(), sub.resolved_name)

    def _publish_link_down(self) -> None:
        """No session: say so on vehicle/state at 10 Hz (FAULT_LINK, measurements unknown)."""
        now = rospy.get_time()
        if 0.0 <= now - self.link_down_published < 0.1:
            return
        self.link_down_published = now
        m = VehicleState()
        m.header.stamp = rospy.Time.now()
        m.header.frame_id = self.p.frame_id
        m.wheel_speed = m.handlebar = m.throttle = m.brake = math.nan
        m.setpoint_speed = m.setpoint_handlebar = math.nan
        m.plc_time = math.nan
        # What is known without a session: the PLC is braking to SAFE (or in HALT), whatever it
        # was last seen in; the next session's first state says for sure
        self.mode = m.mode = mode_without_session(self.mode)
        m.faults = self.faults | protocol.FAULT_LINK
        publish(self.pub_state, m)

    # ------------------------------------------------------------ interlocks
    def _on_interlock(self, msg: Interlock) -> None:
        source = msg.source or msg._connection_header.get("callerid", "?")
        if msg.active:
            if source not in self.interlocks:
                rospy.logwarn("interlock from %s: %s; driving modes refused", source, msg.reason)
            self.interlocks[source] = msg.reason
            if self.mode in DRIVING:
                self._stop_for_interlock()
        elif self.interlocks.pop(source, None) is not None:
            rospy.loginfo("interlock from %s released%s", source,
                          "" if self.interlocks else "; driving modes allowed again")

    def _stop_for_interlock(self) -> None:
        now = rospy.get_time()
        if 0.0 <= now - getattr(self, "_interlock_stop", -1e9) < 0.2:
            return
        self._interlock_stop = now
        self._in_background(self._request_mode, protocol.MODE_SAFE)

    def _in_background(self, fn, *args) -> None:
        """``fn(*args)`` on a thread of its own; in lockstep at once, inside the round (the
        simulator answers the request while it waits for the round)."""
        if self.lockstep is not None:
            fn(*args)
        else:
            threading.Thread(target=fn, args=args, daemon=True).start()

    # ------------------------------------------------------------------ mode
    def _request_mode(self, mode: int):
        """Ask the PLC for ``mode``: (accepted, text, the PLC's mode after the request)."""
        if mode in DRIVING and self.interlocks:
            text = "; ".join(f"{src}: {why}" for src, why in self.interlocks.items())
            msg = f"{protocol.mode_name(mode)} refused: interlock active ({text})"
            rospy.logwarn(msg)
            return False, msg, max(self.mode, 0)
        ack, error = self._ask(protocol.ModeRequest(mode))
        if ack is None:
            return False, error, max(self.mode, 0)
        if ack.status != protocol.OK:
            msg = f"PLC refused {protocol.mode_name(mode)} in {protocol.mode_name(ack.mode)}: {protocol.STATUS_NAMES.get(ack.status)}"
            if ack.status == protocol.NOT_ACKNOWLEDGED:
                msg += f" ({protocol.fault_names(self.faults & LATCHED)}): once the vehicle stands, call " \
                       f"{rospy.resolve_name('~acknowledge')}"
            elif ack.status == protocol.NOT_AT_STANDSTILL:
                msg += " (the wheel and the PLC's accelerometer at rest for its hold time): try again once it stands"
            rospy.logwarn(msg)
            return False, msg, ack.mode
        # The acknowledgement is the PLC's word: forward the new mode's source from now,
        # not from its next state frame (up to 20 ms later, and the service's caller
        # must read the mode it asked for).
        self.mode = ack.mode
        rospy.loginfo("PLC mode %s", protocol.mode_name(ack.mode))
        return True, f"mode {protocol.mode_name(ack.mode)}", ack.mode

    def _ask(self, msg: protocol.Message):
        """Send ``msg`` and wait for its ACK: (ack, "") or (None, why not)."""
        event = threading.Event()
        answer = []
        sent = self.link.send(msg, on_ack=lambda ack: (answer.append(ack), event.set()))
        if sent is None:
            return None, f"not connected to the PLC ({self.link.last_error})"
        if not event.wait(self.p.mode_timeout):
            return None, f"the PLC did not answer within {self.p.mode_timeout} s"
        return answer[0], ""

    def _srv_acknowledge(self, _req) -> TriggerResponse:
        """The operator's reset after a stop for a fault (WATCHDOG, LINK): the PLC takes it at a
        verified standstill only; a driving mode can be requested again after it."""
        latched = self.faults & LATCHED
        ack, error = self._ask(protocol.Reset(LATCHED))
        if ack is None:
            return TriggerResponse(False, error)
        if ack.status != protocol.OK:
            msg = f"PLC refused to acknowledge {protocol.fault_names(latched)}: {protocol.STATUS_NAMES.get(ack.status)}"
            rospy.logwarn(msg)
            return TriggerResponse(False, msg)
        self.faults &= ~LATCHED
        rospy.loginfo("PLC faults acknowledged (%s)", protocol.fault_names(latched))
        return TriggerResponse(True, f"acknowledged {protocol.fault_names(latched)}; mode {protocol.mode_name(ack.mode)}")

    def _srv_set_mode(self, req) -> SetModeResponse:
        if req.mode not in protocol.MODE_NAMES:
            return SetModeResponse(False, f"unknown mode {req.mode}; modes: {protocol.MODE_NAMES}", max(self.mode, 0))
        return SetModeResponse(*self._request_mode(req.mode))

    # ----------------------------------------------------------- diagnostics
    def _diagnose(self, stat):
        link, s = self.link, self.link.stats
        if not link.connected:
            stat.summary(DiagnosticStatus.ERROR, f"not connected: {link.last_error}")
        elif self.interlocks:
            stat.summary(DiagnosticStatus.WARN, f"interlocked: {'; '.join(self.interlocks.values())}")
        elif any(self.mux.stale[src] and self.mux.accepts(self.mode, src) for src in self.mux.stale):
            stat.summary(DiagnosticStatus.WARN, f"mode {protocol.mode_name(self.mode)}: setpoints stale, sending stops")
        else:
            stat.summary(DiagnosticStatus.OK, f"connected, mode {protocol.mode_name(self.mode)}")
        p50, p99, p100 = link.rtt_percentiles(50, 99, 100)
        for key, value in (("address", f"{link.host}:{link.port}"), ("mode", protocol.mode_name(self.mode)),
                           ("faults", str(self.faults)), ("rtt p50 [ms]", f"{p50 * 1e3:.3f}"),
                           ("rtt p99 [ms]", f"{p99 * 1e3:.3f}"), ("rtt max [ms]", f"{p100 * 1e3:.3f}"),
                           ("rtt samples", str(len(link.rtts))), ("frames sent", str(s.frames_sent)),
                           ("frames received", str(s.frames_received)), ("lost frames", str(s.lost_frames)),
                           ("bad frames", str(link.decoder.stats.bad_frames)),
                           ("bad frames by reason", str(link.decoder.stats.errors)),
                           ("setpoints rejected by the PLC", str(self.rejected)),
                           ("bad setpoint messages dropped", str(self.bad_input)),
                           ("frames never acknowledged", str(s.unanswered)),
                           ("frames the PLC found stale", str(s.stale_acks)),
                           ("active interlocks", str(self.interlocks)),
                           ("connects", str(s.connects)), ("disconnects", str(s.disconnects)),
                           ("states read more than 0.1 s late", str(self.clock.late)),
                           ("PLC clock restarts", str(self.clock.restarts)),
                           ("PLC clock", "ROS time" if self.clock.shared else "estimated offset"),
                           ("states whose clock was not ROS time", str(self.clock.mismatch))):
            stat.add(key, value)
        return stat


def main() -> None:
    # The link's I/O thread must get the GIL as soon as a frame arrives, not after the
    # default 5 ms switch interval of whichever rospy thread holds it.
    init_node("plc_client", switch_interval=2e-4)  # joins lockstep when sim.launch lockstep:=true
    PlcClientNode()
    rospy.spin()
