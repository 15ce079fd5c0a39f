"""Excitation node: plays an actuator-calibration program open loop on
``vehicle/setpoint/request`` (:mod:`quadrivio_navigation.excitation`; the obstacle guard passes it on).

Parameters: :class:`quadrivio_navigation.excitation.ExcitationParams` (private; a
scenario's ``excitation:`` section overrides). A bad program (a setpoint beyond
``max_speed`` / ``max_handlebar``) stops the node before it sends anything.

The program's clock starts when the PLC reports AUTO (``vehicle/state``), so no step is
lost to the mode change; it stops and holds the brake if the PLC leaves AUTO (a driver's
takeover, the roll-over monitor, a lost link) and does not resume by itself. When the
clock moves back (the simulator's ``~reset``) the program starts over. Publishes
``vehicle/setpoint/request`` (quadrivio_plc/Setpoint) at ``~rate``, with the program's phase
in ``/diagnostics``.
"""

from __future__ import annotations

import threading
from typing import Optional

import rospy
from diagnostic_msgs.msg import DiagnosticStatus

from quadrivio_runtime.ros import init_node
from quadrivio_config import ConfigError
from quadrivio_runtime.ros import diagnostics
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import fatal, node_params, with_scenario
from quadrivio_runtime.ros.timer import guarded_timer, on_clock_jump, publish
from quadrivio_plc.msg import Setpoint, VehicleState

from ..excitation import ExcitationParams, build


class ExcitationNode:
    def __init__(self) -> None:
        self.p: ExcitationParams = with_scenario(node_params(ExcitationParams), "excitation")
        try:
            self.program = build(self.p)
        except ConfigError as exc:
            fatal(str(exc))
        self.lock = threading.Lock()
        self.t0: Optional[float] = None  # program start (sim time)
        self.stopped = ""  # why the program was cut short
        self.done = False
        self.mode = -1
        self.pub = direct_publisher("vehicle/setpoint/request", Setpoint, queue_size=10)
        rospy.Subscriber("vehicle/state", VehicleState, self._on_state, queue_size=10)
        on_clock_jump(self._on_clock_jump)
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("excitation")
        self.diag.add("excitation", self._diagnose)
        guarded_timer(1.0 / self.p.rate, self._tick, "excitation cycle")
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        rospy.loginfo("excitation: %.1f s of steps and sweeps, waiting for the PLC in AUTO", self.program.duration)

    def _on_clock_jump(self, before: float, now: float) -> None:
        with self.lock:
            self.t0, self.stopped, self.done = None, "", False
        rospy.logwarn("excitation: the clock moved back (%.2f -> %.2f s); the program starts over", before, now)

    def _on_state(self, m: VehicleState) -> None:
        now = rospy.get_time()
        with self.lock:
            self.mode = m.mode
            if m.faults & VehicleState.FAULT_LINK:
                return
            if m.mode == VehicleState.MODE_AUTO and self.t0 is None and not self.stopped:
                self.t0 = now
                rospy.loginfo("excitation: the PLC is in AUTO, program started at %.2f s", now)
            elif m.mode != VehicleState.MODE_AUTO and self.t0 is not None and not self.done and not self.stopped:
                self.stopped = f"the PLC left AUTO (mode {m.mode}) at {now:.2f} s"
                rospy.logwarn("excitation: %s; braking, the program is not resumed", self.stopped)

    def _tick(self, _event) -> None:
        now = rospy.get_time()
        with self.lock:
            if self.t0 is None or self.stopped:
                speed, handlebar, brake = 0.0, 0.0, 1.0
            else:
                speed, handlebar, brake = self.program.at(now - self.t0)
                if not self.done and now - self.t0 >= self.program.duration:
                    self.done = True
                    rospy.loginfo("excitation: program done at %.2f s; standing with the brake on", now)
        sp = Setpoint()
        sp.header.stamp = rospy.Time.from_sec(now)
        sp.speed, sp.handlebar, sp.brake = speed, handlebar, brake
        publish(self.pub, sp)

    def _diagnose(self, stat):
        with self.lock:
            if self.stopped:
                stat.summary(DiagnosticStatus.WARN, f"stopped: {self.stopped}")
            elif self.t0 is None:
                stat.summary(DiagnosticStatus.OK, "waiting for the PLC in AUTO")
            elif self.done:
                stat.summary(DiagnosticStatus.OK, "done")
            else:
                stat.summary(DiagnosticStatus.OK, f"running, {rospy.get_time() - self.t0:.1f} of "
                                                  f"{self.program.duration:.1f} s")
        return stat


def main() -> None:
    init_node("excitation")  # joins lockstep when sim.launch lockstep:=true
    ExcitationNode()
    rospy.spin()
