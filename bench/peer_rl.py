"""robot_localization (the peer) on exactly the readings our smoother got, in lockstep sim time.

The peer runs as users run it: ``ekf_localization_node`` in ``two_d_mode`` and
``navsat_transform_node`` with a manual datum at our site's origin and
``use_local_cartesian`` (our map frame to under a millimetre, ../shared/peers/README.md), on
a ROS master of its own with ``/use_sim_time``. This driver publishes ``/clock`` itself
and the recorded readings of an offline run (:class:`quadrivio.offline.Inputs`) at their
delivery times:

* ``/wheel/twist`` (TwistWithCovarianceStamped, base_link): forward speed from the wheel,
  yaw rate ``v tan(handlebar x ratio) / L``, lateral speed 0 (no slip), from each PLC state;
* ``/imu/data`` (Imu, base_link): the gyro's yaw rate, and the yaw of the levelled
  magnetometer under the calibration both sides get (our smoother's priors: the simulated
  magnetometer's calibration, or none at all), as a compass-aided IMU driver would give it;
* ``/gps/fix`` (NavSatFix, gps_link with its lever arm on /tf_static), as received.

Lockstep: the clock advances one physics step (10 ms) at a time; before each filter period
boundary the driver waits (on the condition, with a wall timeout) for the filter's output
of the previous period, so the filter never runs ahead or behind the readings. Message
delivery between topics is still asynchronous, so two runs may differ slightly: the
benchmark measures that spread and reports it.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import tempfile
import threading
import time
from typing import Dict, Optional

import numpy as np

from quadrivio_description.frames import quaternion_from_yaw, yaw_from_quaternion
from quadrivio_runtime.files import atomic_path

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def peer_config(frequency: float, site) -> str:
    """rosparam YAML of both nodes: ekf under /ekf, navsat under /navsat."""
    lat, lon = site.datum.latitude, site.datum.longitude
    return f"""
ekf:
  frequency: {frequency}
  sensor_timeout: 0.5
  two_d_mode: true
  publish_tf: true
  predict_to_current_time: true
  map_frame: map
  odom_frame: odom
  base_link_frame: base_link
  world_frame: odom
  transform_time_offset: 0.0
  twist0: /wheel/twist
  twist0_config: [false, false, false, false, false, false, true, true, false, false, false, true, false, false, false]
  twist0_queue_size: 20
  imu0: /imu/data
  imu0_config: [false, false, false, false, false, true, false, false, false, false, false, true, false, false, false]
  imu0_queue_size: 50
  imu0_remove_gravitational_acceleration: false
  odom0: /odometry/gps
  odom0_config: [true, true, false, false, false, false, false, false, false, false, false, false, false, false, false]
  odom0_queue_size: 10
  odom0_differential: false
navsat:
  frequency: {frequency}
  delay: 0.0
  magnetic_declination_radians: 0.0
  yaw_offset: 0.0
  zero_altitude: true
  broadcast_cartesian_transform: false
  publish_filtered_gps: false
  use_odometry_yaw: false
  wait_for_datum: true
  use_local_cartesian: true
  datum: [{lat!r}, {lon!r}, 0.0]
"""


class PeerRun:
    """One robot_localization run on one offline run's inputs (see module docstring)."""

    def __init__(self, setup_bash: str, vehicle, site, frequency: float = 20.0) -> None:
        self.setup_bash, self.v, self.site, self.frequency = setup_bash, vehicle, site, frequency

    def run(self, inputs: Dict[str, np.ndarray], mag_calibration: Optional[np.ndarray], t_end: float,
            dt: float = 0.01, log_dir: Optional[str] = None) -> np.ndarray:
        """Returns [t, x, y, yaw] of the filter's output in the map frame, one row per period."""
        port = _free_port()
        uri = f"http://127.0.0.1:{port}"
        log_dir = log_dir or tempfile.mkdtemp(prefix="peer_rl_")
        os.makedirs(log_dir, exist_ok=True)
        env = dict(os.environ, ROS_MASTER_URI=uri, ROS_LOG_DIR=log_dir)
        procs = []

        def spawn(cmd: str, log: str) -> subprocess.Popen:
            fh = open(os.path.join(log_dir, log), "w")
            p = subprocess.Popen(["bash", "-c", f"source {self.setup_bash} && exec {cmd}"], env=env, stdout=fh,
                                 stderr=subprocess.STDOUT, start_new_session=True)
            procs.append(p)
            return p

        cfg = os.path.join(log_dir, "peer.yaml")
        with open(cfg, "w") as f:
            f.write(peer_config(self.frequency, self.site))
        try:
            spawn(f"roscore -p {port}", "roscore.log")
            self._wait_master(uri)
            subprocess.run(["bash", "-c", f"source {self.setup_bash} && rosparam set /use_sim_time true && "
                                          f"rosparam load {cfg}"], env=env, check=True, capture_output=True)
            os.environ["ROS_MASTER_URI"] = uri
            return self._drive(inputs, mag_calibration, t_end, dt, spawn)
        finally:
            for p in reversed(procs):
                try:
                    os.killpg(p.pid, 2)
                except ProcessLookupError:
                    pass
            for p in procs:
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    os.killpg(p.pid, 9)

    @staticmethod
    def _wait_master(uri: str, timeout: float = 30.0) -> None:
        import xmlrpc.client

        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                xmlrpc.client.ServerProxy(uri).getPid("/peer_rl")
                return
            except OSError:
                time.sleep(0.05)
        raise RuntimeError(f"roscore at {uri} did not start")

    def _drive(self, inputs, mag_cal, t_end, dt, spawn) -> np.ndarray:
        import rospy
        import tf2_ros
        from geometry_msgs.msg import TransformStamped, TwistWithCovarianceStamped
        from nav_msgs.msg import Odometry
        from rosgraph_msgs.msg import Clock
        from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus

        from quadrivio_localization import factors as F
        from quadrivio_localization.leveling import Leveller

        rospy.init_node("peer_rl_driver", disable_signals=True)
        pub_clock = rospy.Publisher("/clock", Clock, queue_size=10, latch=True)
        pub_twist = rospy.Publisher("/wheel/twist", TwistWithCovarianceStamped, queue_size=100)
        pub_imu = rospy.Publisher("/imu/data", Imu, queue_size=200)
        pub_fix = rospy.Publisher("/gps/fix", NavSatFix, queue_size=20)
        outputs = []
        lock = threading.Condition()

        def on_odom(m: Odometry) -> None:
            q = m.pose.pose.orientation
            yaw = yaw_from_quaternion(q.x, q.y, q.z, q.w)
            with lock:
                outputs.append((m.header.stamp.to_sec(), m.pose.pose.position.x, m.pose.pose.position.y, yaw))
                lock.notify_all()

        rospy.Subscriber("/odometry/filtered", Odometry, on_odom, queue_size=1000)
        clock = Clock()
        clock.clock = rospy.Time.from_sec(0.001)  # the nodes wait for a non-zero clock
        pub_clock.publish(clock)
        static = tf2_ros.StaticTransformBroadcaster()
        tfs = []
        for frame in ("gps_link", "imu_link"):
            x, y, z = self.v.sensors[frame].xyz
            tr = TransformStamped()
            tr.header.frame_id, tr.child_frame_id = "base_link", frame
            tr.transform.translation.x, tr.transform.translation.y, tr.transform.translation.z = x, y, z
            tr.transform.rotation.w = 1.0
            tfs.append(tr)
        static.sendTransform(tfs)
        spawn("rosrun robot_localization ekf_localization_node __name:=ekf", "ekf.log")
        spawn("rosrun robot_localization navsat_transform_node __name:=navsat "
              "odometry/filtered:=/odometry/filtered gps/fix:=/gps/fix imu/data:=/imu/data "
              "odometry/gps:=/odometry/gps", "navsat.log")
        for topic, pub in (("/clock", pub_clock), ("/wheel/twist", pub_twist), ("/imu/data", pub_imu),
                           ("/gps/fix", pub_fix)):
            deadline = time.monotonic() + 60.0
            while pub.get_num_connections() < (2 if topic == "/clock" else 1):
                if time.monotonic() > deadline:
                    raise RuntimeError(f"the peer did not subscribe {topic} within 60 s")
                time.sleep(0.02)

        h_en = self.site.magnetic_field.enu()
        h_en = (h_en[0] * 1e6, h_en[1] * 1e6)
        cal = mag_cal if mag_cal is not None else np.array([0.0, 0.0, 1.0, 1.0, 0.0])
        lev = Leveller(self.v, 1.0)
        L, ratio = self.v.wheelbase, self.v.steering.ratio
        last_w = [0.0]
        events = []
        for row in inputs["state"]:
            events.append((row[0], 0, "state", row))
        for row in inputs["imu"]:
            events.append((row[0], 1, "imu", row))
        for row in inputs["mag"]:
            events.append((row[0], 2, "mag", row))
        for row in inputs["gps"]:
            events.append((row[0], 3, "gps", row))
        events.sort(key=lambda e: (e[0], e[1]))
        mag_yaw = [None]

        def stamp_of(t):
            return rospy.Time.from_sec(t)

        def publish(kind, row) -> None:
            if kind == "state":
                _, t, v, h = row
                lev.add_speed(t, v)
                m = TwistWithCovarianceStamped()
                m.header.stamp, m.header.frame_id = stamp_of(t), "base_link"
                m.twist.twist.linear.x = v
                m.twist.twist.angular.z = v * math.tan(h * ratio) / L
                cov = [0.0] * 36
                cov[0], cov[7], cov[35] = 0.05 ** 2, 0.05 ** 2, 0.05 ** 2
                for i in (14, 21, 28):
                    cov[i] = 1e3
                m.twist.covariance = cov
                pub_twist.publish(m)
            elif kind == "imu":
                _, t, fx, fy, fz, wx, wy, wz = row
                last_w[0] = lev.add_imu(t, (fx, fy, fz), (wx, wy, wz))
                if mag_yaw[0] is None:
                    return
                m = Imu()
                m.header.stamp, m.header.frame_id = stamp_of(t), "base_link"
                yaw = mag_yaw[0]
                m.orientation.x, m.orientation.y, m.orientation.z, m.orientation.w = quaternion_from_yaw(yaw)
                m.orientation_covariance = [1e3, 0, 0, 0, 1e3, 0, 0, 0, 0.05 ** 2]
                m.angular_velocity.z = last_w[0]
                m.angular_velocity_covariance = [1e3, 0, 0, 0, 1e3, 0, 0, 0, 0.02 ** 2]
                m.linear_acceleration_covariance = [-1.0, 0, 0, 0, 0, 0, 0, 0, 0]
                pub_imu.publish(m)
            elif kind == "mag":
                _, t, mx, my, mz = row
                lx, ly = lev.level_mag((mx, my, mz))
                mag_yaw[0] = F.mag_heading((lx * 1e6, ly * 1e6), cal, h_en)
            else:
                _, t, lat, lon, alt, ve, vn, status = row
                m = NavSatFix()
                m.header.stamp, m.header.frame_id = stamp_of(t), "gps_link"
                m.status.status, m.status.service = int(status), NavSatStatus.SERVICE_GPS
                m.latitude, m.longitude, m.altitude = lat, lon, alt
                if status >= 0:
                    m.position_covariance = [ve, 0, 0, 0, vn, 0, 0, 0, max(ve, vn) * 4]
                    m.position_covariance_type = NavSatFix.COVARIANCE_TYPE_DIAGONAL_KNOWN
                pub_fix.publish(m)

        period = 1.0 / self.frequency
        i = 0
        steps = int(round(t_end / dt))
        for k in range(1, steps + 1):
            t = k * dt
            while i < len(events) and events[i][0] <= t + 1e-9:
                publish(events[i][2], events[i][3])
                i += 1
            clock.clock = rospy.Time.from_sec(t)
            pub_clock.publish(clock)
            if abs(t / period - round(t / period)) < 1e-6 and t > 2 * period:
                # wait for the output of the filter period that just ended (once the filter runs)
                with lock:
                    if outputs:
                        ok = lock.wait_for(lambda: outputs[-1][0] >= t - period - 1e-6, timeout=2.0)
                        if not ok and os.environ.get("PEER_DEBUG"):
                            print("timeout at", t, "last output", outputs[-1][0], flush=True)
        rospy.signal_shutdown("done")
        return np.array(outputs).reshape(-1, 4)


def main(argv=None) -> int:
    """``python3 bench/peer_rl.py SETUP_BASH INPUTS.npz OUT.npz``: one run in its own process
    (a ROS node per process). INPUTS.npz: arrays state, imu, mag, gps, t_end, and mag_cal
    (empty: no calibration)."""
    import sys

    from quadrivio_description.site import load_site
    from quadrivio_description.vehicle import load_vehicle

    args = sys.argv[1:] if argv is None else argv
    if len(args) != 3:
        print(main.__doc__, file=sys.stderr)
        return 2
    setup, src, dst = args
    d = np.load(src)
    cal = d["mag_cal"] if d["mag_cal"].size else None
    out = PeerRun(setup, load_vehicle(), load_site()).run(
        {k: d[k] for k in ("state", "imu", "mag", "gps")}, cal, float(d["t_end"]),
        log_dir=os.path.join(os.path.dirname(os.path.abspath(dst)), "peer_logs_" + os.path.basename(dst)[:-4]))
    with atomic_path(dst) as tmp:
        np.savez_compressed(tmp, estimate=out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
