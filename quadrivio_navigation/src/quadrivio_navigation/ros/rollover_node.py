"""Roll-over monitor node: warns and can stop the vehicle when it is about to tip over.

Parameters (private, ``config/rollover.yaml``): the thresholds of
:class:`quadrivio_navigation.rollover.RolloverParams`, ``~stop_on_trip`` (bool, true:
ask the PLC for SAFE, i.e. brake and hold, on a trip), ``~set_mode_service``
(str, /plc_client/set_mode).
Subscribes: ``imu/data`` (sensor_msgs/Imu), ``vehicle/state`` (quadrivio_plc/VehicleState:
while tripped, a PLC found in a driving mode is sent back to SAFE, at most once a
second). Publishes: ``safety/rollover`` (quadrivio_navigation/RolloverRisk) for every
IMU sample, ``safety/interlock`` (quadrivio_plc/Interlock, latched: active while tripped
and ``~stop_on_trip``, so that the PLCClient refuses driving modes at once), ``/diagnostics``.
IMU samples with non-finite values or stamps ahead of the clock are dropped and counted.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass

import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from sensor_msgs.msg import Imu

from quadrivio_runtime.ros import init_node
from quadrivio_config import param
from quadrivio_description.frames import rotate
from quadrivio_runtime.ros import diagnostics
from quadrivio_runtime.ros.direct import direct_publisher
from quadrivio_runtime.ros.params import node_params, private_params, split_params, vehicle_params
from quadrivio_runtime.ros.timer import check_clock, guarded_timer, input_guard, on_clock_jump, publish

from ..msg import RolloverRisk
from ..rollover import LEVEL_NAMES, OK, TRIP, RolloverMonitor, RolloverParams


@dataclass(frozen=True)
class NodeParams:
    stop_on_trip: bool = param(True, doc="request SAFE from the PLC on a trip")
    set_mode_service: str = param("/plc_client/set_mode", doc="the PLCClient's SetMode service")


class RolloverNode:
    def __init__(self) -> None:
        mine, rest = split_params(private_params(), NodeParams)
        self.node_params: NodeParams = node_params(NodeParams, mine)
        self.p: RolloverParams = node_params(RolloverParams, rest)
        vehicle = vehicle_params()
        self.ssf = vehicle.static_stability_factor
        self.mount = vehicle.sensors["imu_link"].rpy
        self.monitor = RolloverMonitor(self.p, self.ssf)
        self.guard = input_guard()
        self.pub = direct_publisher("safety/rollover", RolloverRisk, queue_size=20)
        self.pub_interlock = None
        if self.node_params.stop_on_trip:
            from quadrivio_plc.msg import Interlock

            self.pub_interlock = rospy.Publisher("safety/interlock", Interlock, queue_size=5, latch=True)
            self._interlock(False, "no roll-over risk")
        self.last = None
        self.level = OK
        self.stopping = threading.Lock()
        self.diag = diagnostics.updater()
        self.diag.setHardwareID("rollover monitor")
        self.diag.add("roll-over risk", self._diagnose)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        rospy.Subscriber("imu/data", Imu, self._on_imu, queue_size=50)
        if self.node_params.stop_on_trip:
            from quadrivio_plc.msg import VehicleState

            rospy.Subscriber("vehicle/state", VehicleState, self._on_state, queue_size=5)
        self.last_request = -1e9
        on_clock_jump(self._on_clock_jump)
        rospy.loginfo("roll-over monitor: static stability factor %.2f, warn at %.0f %%, trip at %.0f %%",
                      self.ssf, 100 * self.p.warn_ratio, 100 * self.p.trip_ratio)

    def _on_clock_jump(self, _before: float, _now: float) -> None:
        self.monitor = RolloverMonitor(self.p, self.ssf)
        self.last_request = -1e9
        self.level, self.last = OK, None
        if self.pub_interlock is not None:
            self._interlock(False, "clock moved back: monitor restarted")

    def _interlock(self, active: bool, reason: str) -> None:
        from quadrivio_plc.msg import Interlock

        m = Interlock()
        m.header.stamp = rospy.Time.now()
        m.source, m.active, m.reason = rospy.get_name(), active, reason
        publish(self.pub_interlock, m)

    def _on_imu(self, m: Imu) -> None:
        a, w = m.linear_acceleration, m.angular_velocity
        check_clock()
        if not self.guard.check("imu/data", m.header.stamp.to_sec(), rospy.get_time(), a.x, a.y, a.z, w.x, w.y, w.z):
            return
        f = rotate(self.mount, (a.x, a.y, a.z))
        g = rotate(self.mount, (w.x, w.y, w.z))
        s = self.monitor.update(m.header.stamp.to_sec(), f, g)
        out = RolloverRisk()
        out.header.stamp = m.header.stamp
        out.header.frame_id = "base_link"
        out.risk, out.roll, out.lateral_accel, out.level = s.risk, s.roll, s.lateral_accel, s.level
        out.static_stability_factor = self.ssf
        if not publish(self.pub, out):
            return
        if s.level != self.level:
            log = rospy.logerr if s.level == TRIP else rospy.logwarn if s.level > OK else rospy.loginfo
            log("roll-over risk %s: %.0f %% of tipping, roll %.1f deg", LEVEL_NAMES[s.level], 100 * s.risk,
                s.roll * 57.29578)
            if self.pub_interlock is not None and TRIP in (s.level, self.level):
                self._interlock(s.level == TRIP, f"roll-over risk {LEVEL_NAMES[s.level]}: {100 * s.risk:.0f} % "
                                                  f"of tipping, roll {s.roll * 57.29578:.1f} deg")
            if s.level == TRIP and self.node_params.stop_on_trip:
                self._request_stop()
        self.level, self.last = s.level, s

    def _on_state(self, m) -> None:
        # While tripped the vehicle must not drive: whoever asked for a driving mode, back to SAFE.
        if self.level == TRIP and m.mode in (m.MODE_MANUAL, m.MODE_ASSISTED, m.MODE_AUTO):
            self._request_stop()

    def _request_stop(self) -> None:
        now = rospy.get_time()
        if now - self.last_request < 1.0:
            return
        self.last_request = now
        threading.Thread(target=self._stop, daemon=True).start()

    def _stop(self) -> None:
        from quadrivio_plc.msg import VehicleState
        from quadrivio_plc.srv import SetMode

        if not self.stopping.acquire(blocking=False):
            return
        try:
            rospy.wait_for_service(self.node_params.set_mode_service, timeout=2.0)
            r = rospy.ServiceProxy(self.node_params.set_mode_service, SetMode)(VehicleState.MODE_SAFE)
            (rospy.logwarn if r.success else rospy.logerr)("roll-over trip: PLC to SAFE: %s", r.message)
        except (rospy.ROSException, rospy.ServiceException) as exc:
            rospy.logerr("roll-over trip: could not stop the vehicle through %s: %s", self.node_params.set_mode_service, exc)
        finally:
            self.stopping.release()

    def _diagnose(self, stat):
        s = self.last
        if s is None:
            stat.summary(DiagnosticStatus.WARN, "no IMU data")
            return stat
        level = {OK: DiagnosticStatus.OK, 1: DiagnosticStatus.WARN, TRIP: DiagnosticStatus.ERROR}[s.level]
        stat.summary(level, f"{LEVEL_NAMES[s.level]}: {100 * s.risk:.0f} % of tipping")
        stat.add("risk", f"{s.risk:.3f}")
        stat.add("roll [deg]", f"{s.roll * 57.29578:.1f}")
        stat.add("lateral acceleration [m/s^2]", f"{s.lateral_accel:.2f}")
        stat.add("static stability factor", f"{self.ssf:.3f}")
        stat.add("IMU samples rejected", self.guard.summary())
        return stat


def main() -> None:
    init_node("rollover_monitor")  # joins lockstep when sim.launch lockstep:=true
    RolloverNode()
    rospy.spin()
