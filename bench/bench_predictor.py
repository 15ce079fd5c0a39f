"""Benchmark: timing of the 50 Hz predictor (roscpp) on the wall clock, as on the vehicle.

The predictor node runs alone on a private master with wall time (use_sim_time false),
fed by this process with /localization/odom at 20 Hz and /vehicle/state at 50 Hz (a
vehicle driving a circle at 2 m/s) while two background processes keep the 2 cores
busy (about 40 % of a core each, in bursts, as the stack's Python nodes do). Each
/localization/predicted message is stamped by the predictor with the time its timer
fired (horizon 0): the deviation of consecutive stamps from 20 ms is the publish period's
jitter. The receipt times in this (Python) process are reported too; they add rospy's
own delivery jitter.

The predictor runs as shipped (``config/predictor.yaml``: its 50 Hz beat on a thread of
its own at real-time priority ``realtime_priority``), then, side by side, at normal
priority (keys ``*_normal_priority``).

Keys: predictor_jitter_p99_ms (stamps), predictor_jitter_p50_ms, predictor_receipt_jitter_p99_ms,
predictor_missed (periods over 30 ms). Writes bench/results/predictor.json.
"""
import math
import os
import subprocess
import sys
import threading
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, ros_session, wait_for, write_result  # noqa: E402

WALL = 60.0
LOAD = ("import time\nt = time.monotonic()\nwhile time.monotonic() - t < {s}:\n"
        "    sum(i * i for i in range(100000)); time.sleep(0.01)\n")  # about 40 % of a core each


def shipped_priority() -> int:
    import yaml

    path = os.path.join(subprocess.run(["rospack", "find", "quadrivio_localization"], capture_output=True, text=True,
                                       check=True).stdout.strip(), "config", "predictor.yaml")
    with open(path) as fh:
        return int(yaml.safe_load(fh).get("realtime_priority", 0))


def measure(priority: int) -> dict:
    with ros_session() as ros:
        subprocess.run(["rosparam", "set", "/use_sim_time", "false"], check=True)
        subprocess.run(["rosparam", "load", os.path.join(
            subprocess.run(["rospack", "find", "quadrivio_description"], capture_output=True, text=True,
                           check=True).stdout.strip(), "config", "vehicle.yaml"), "/vehicle"], check=True)
        ros.procs.append(ros._spawn(["rosrun", "quadrivio_localization", "predictor", "_rate:=50.0",
                                    f"_realtime_priority:={priority}"], "predictor"))
        import rospy
        from nav_msgs.msg import Odometry
        from quadrivio_plc.msg import VehicleState

        rospy.init_node("bench_predictor", anonymous=True, disable_signals=True)
        stamps, receipts = [], []

        def on_pred(m):
            receipts.append(time.monotonic())
            stamps.append(m.header.stamp.to_sec())

        rospy.Subscriber("/localization/predicted", Odometry, on_pred, queue_size=100)
        pub_odom = rospy.Publisher("/localization/odom", Odometry, queue_size=10)
        pub_state = rospy.Publisher("/vehicle/state", VehicleState, queue_size=10)
        stop = threading.Event()

        def feed():
            k, t0 = 0, time.monotonic()
            while not stop.is_set():
                now = rospy.Time.now()
                s = VehicleState()
                s.header.stamp = now
                s.wheel_speed, s.handlebar, s.mode = 2.0, 0.2, VehicleState.MODE_AUTO
                pub_state.publish(s)
                if k % 5 == 0:  # 20 Hz of estimates along a circle
                    tt = now.to_sec()
                    o = Odometry()
                    o.header.stamp, o.header.frame_id, o.child_frame_id = now, "map", "base_link"
                    o.pose.pose.position.x, o.pose.pose.position.y = 10 * math.cos(0.2 * tt), 10 * math.sin(0.2 * tt)
                    o.pose.pose.orientation.z, o.pose.pose.orientation.w = math.sin(0.1 * tt), math.cos(0.1 * tt)
                    pub_odom.publish(o)
                k += 1
                time.sleep(max(0.0, t0 + 0.02 * k - time.monotonic()))

        threading.Thread(target=feed, daemon=True).start()
        wait_for(lambda: len(stamps) > 50, 60, "the predictor's first predictions")
        load = [subprocess.Popen([sys.executable, "-c", LOAD.format(s=WALL + 5)]) for _ in range(2)]
        print(f"[bench predictor] real-time priority {priority}: measuring {WALL:.0f} wall s with two background "
              "load processes ...", flush=True)
        n0 = len(stamps)
        time.sleep(WALL)
        n1 = len(stamps)
        stop.set()
        for p in load:
            p.kill()
    st = np.diff(np.array(stamps[n0:n1])) * 1e3
    rc = np.diff(np.array(receipts[n0:n1])) * 1e3
    dev, rdev = np.abs(st - 20.0), np.abs(rc - 20.0)
    result = {"predictor_jitter_p99_ms": float(np.percentile(dev, 99)),
              "predictor_jitter_p50_ms": float(np.percentile(dev, 50)),
              "predictor_jitter_max_ms": float(dev.max()),
              "predictor_receipt_jitter_p99_ms": float(np.percentile(rdev, 99)),
              "predictor_missed": int(np.sum(st > 30.0)), "periods": int(st.size),
              "predictor_rate_hz": float(1e3 / st.mean())}
    print(f"[bench predictor] period deviation p50 {result['predictor_jitter_p50_ms']:.3f} ms, p99 "
          f"{result['predictor_jitter_p99_ms']:.3f} ms over {st.size} periods "
          f"({result['predictor_rate_hz']:.2f} Hz)", flush=True)
    return result


def measured(priority: int) -> dict:
    """measure(priority) in a process of its own (rospy joins one master per process)."""
    import json

    r = subprocess.run([sys.executable, os.path.abspath(__file__), "--measure", str(priority)],
                       stdout=subprocess.PIPE, text=True, check=True)
    lines = r.stdout.strip().splitlines()
    print("\n".join(lines[:-1]), flush=True)
    return json.loads(lines[-1])


def main():
    if len(sys.argv) == 3 and sys.argv[1] == "--measure":
        import json

        print(json.dumps(measure(int(sys.argv[2]))), flush=True)
        return
    prio = shipped_priority()
    result = measured(prio)  # as shipped (config/predictor.yaml)
    result["realtime_priority"] = prio
    if prio > 0:  # the same at normal priority, side by side
        for k, v in measured(0).items():
            result[f"{k}_normal_priority"] = v
    result.update(scenario="predictor alone on wall time, fed at 20 Hz (odom) and 50 Hz (state), two background "
                           "processes at about 40 % of a core each; as shipped, then at normal priority",
                  machine=machine())
    write_result("predictor", result)


if __name__ == "__main__":
    main()
