"""NMEA GPS driver node: NMEA 0183 over a serial port, pseudo-terminal or TCP -> NavSatFix.

Parameters (private): ``~device`` (str, "/dev/ttyUSB0": serial port or pty path; used when
``~tcp`` is empty), ``~baud`` (int, 115200), ``~tcp`` (str, "": ``host:port`` of a
networked receiver), ``~frame_id`` (str, gps_link), ``~fix_delay`` (float s, 0: subtracted
from the receipt time to stamp a fix), ``~reconnect_period`` (float s, 1.0).

Publishes: ``fix`` (sensor_msgs/NavSatFix, one per GGA epoch, NO_FIX with NaN position
when the receiver has none), ``vel`` (geometry_msgs/TwistStamped, ENU velocity from
RMC), ``/diagnostics``.
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import rospy
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import NavSatFix, NavSatStatus

from quadrivio_config import param
from quadrivio_runtime.ros import diagnostics, init_node
from quadrivio_runtime.ros.params import node_params
from quadrivio_runtime.ros.timer import guarded_timer

from ..nmea import NO_FIX, Fix, NmeaFixParser, Velocity
from ..transports import serial_lines, tcp_lines


@dataclass(frozen=True)
class DriverParams:
    device: str = param("/dev/ttyUSB0", doc="serial port or pseudo-terminal of the receiver")
    baud: int = param(115200, lo=1200, hi=4000000, doc="serial baud rate")
    tcp: str = param("", doc="host:port of a networked receiver (instead of device)")
    frame_id: str = param("gps_link", doc="antenna frame")
    fix_delay: float = param(0.0, lo=0.0, hi=5.0, unit="s", doc="subtracted from the receipt time to stamp a fix")
    reconnect_period: float = param(1.0, lo=0.05, hi=60.0, unit="s", doc="wait between attempts to reopen")


class NmeaGpsNode:
    def __init__(self) -> None:
        self.p: DriverParams = node_params(DriverParams)
        self.parser = NmeaFixParser()
        self.pub_fix = rospy.Publisher("fix", NavSatFix, queue_size=10)
        self.pub_vel = rospy.Publisher("vel", TwistStamped, queue_size=10)
        self.source = f"tcp://{self.p.tcp}" if self.p.tcp else self.p.device
        self.connected = False
        self.last_error = ""
        self.last_status = None
        self.last_fix_wall = None
        self.diag = diagnostics.updater()
        self.diag.setHardwareID(f"NMEA GPS {self.source}")
        self.diag.add("GPS", self._diagnose)
        guarded_timer(1.0, lambda _: self.diag.update(), "diagnostics")
        threading.Thread(target=self._run, name="nmea_reader", daemon=True).start()

    def _lines(self):
        if self.p.tcp:
            host, _, port = self.p.tcp.rpartition(":")
            return tcp_lines(host or "127.0.0.1", int(port))
        return serial_lines(self.p.device, self.p.baud)

    def _run(self) -> None:
        stop = threading.Event()
        rospy.on_shutdown(stop.set)
        while not stop.is_set():
            try:
                for line in self._lines():
                    if not self.connected:
                        self.connected = True
                        rospy.loginfo("reading NMEA from %s", self.source)
                    if stop.is_set():
                        return
                    if line:
                        self._handle(line)
            except OSError as exc:
                self.connected = False
                self.last_error = str(exc)
                rospy.logwarn_throttle(10.0, "%s; retrying every %.1f s", exc, self.p.reconnect_period)
                stop.wait(self.p.reconnect_period)

    def _handle(self, line: str) -> None:
        now = rospy.Time.now()
        for out in self.parser.feed_line(line, now.to_sec()):
            if isinstance(out, Fix):
                self._publish_fix(out)
            elif isinstance(out, Velocity):
                m = TwistStamped()
                m.header.stamp = rospy.Time.from_sec(max(0.0, out.received - self.p.fix_delay))
                m.header.frame_id = self.p.frame_id
                m.twist.linear.x, m.twist.linear.y = out.east, out.north
                self.pub_vel.publish(m)
        for problem in self.parser.pop_problems():
            rospy.logwarn_throttle(5.0, "NMEA sentence from %s rejected (%s); skipped", self.source, problem)

    def _publish_fix(self, f: Fix) -> None:
        m = NavSatFix()
        m.header.stamp = rospy.Time.from_sec(max(0.0, f.received - self.p.fix_delay))
        m.header.frame_id = self.p.frame_id
        m.status.status = f.status
        m.status.service = NavSatStatus.SERVICE_GPS
        m.latitude, m.longitude, m.altitude = f.latitude, f.longitude, f.altitude
        m.position_covariance = list(f.covariance)
        m.position_covariance_type = f.covariance_type
        self.pub_fix.publish(m)
        self.last_status = f.status
        if f.status != NO_FIX:
            self.last_fix_wall = rospy.get_time()

    def _diagnose(self, stat):
        s = self.parser.stats
        if not self.connected:
            stat.summary(DiagnosticStatus.ERROR, f"no data: {self.last_error or 'not opened yet'}")
        elif self.last_status in (None, NO_FIX):
            stat.summary(DiagnosticStatus.WARN, "no fix")
        else:
            stat.summary(DiagnosticStatus.OK, f"fix (status {self.last_status})")
        age = math.nan if self.last_fix_wall is None else rospy.get_time() - self.last_fix_wall
        for key, value in (("source", self.source), ("sentences", str(s.sentences)), ("fixes", str(s.fixes)),
                           ("rejected sentences", str(s.errors)), ("time since last fix [s]", f"{age:.1f}")):
            stat.add(key, value)
        return stat


def main() -> None:
    init_node("nmea_gps", lockstep=False)  # the real driver: outside the simulated loop
    NmeaGpsNode()
    rospy.spin()
