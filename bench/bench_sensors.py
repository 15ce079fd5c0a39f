"""Benchmark: CPU used by the simulator plus every sensor adapter at real-time factor 1
(cameras off), as a fraction of one core.

Launches the simulator (with its emulated PLC) and the layer-2 adapters (GPS, IMU,
magnetometer, two lasers) while the vehicle drives a slalom, lets them run 60 wall
seconds after a warm-up, and sums the
CPU time of those processes from /proc.

Keys: sensors_cpu_frac (all of them), and per node. Writes bench/results/sensors.json.
"""
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, node_pid, process_cpu_seconds, ros_session, write_result  # noqa: E402

NODES = ["/simulator", "/sensor_adapters"]  # the five adapters are one process (adapters.launch)
WALL = 60.0


def main():
    with ros_session() as ros:
        ros.launch("quadrivio_sim", "bench_sensors.launch",
                   "script_file:=" + os.path.join(HERE, "data", "slalom.csv"),
                   "steps_per_wake:=" + os.environ.get("SENSORS_STEPS_PER_WAKE", ""))  # A/B: 1 = a wait every step
        import rosnode

        deadline = time.monotonic() + 120
        while time.monotonic() < deadline:
            try:
                if set(NODES) <= set(rosnode.get_node_names()):
                    break
            except rosnode.ROSNodeIOException:
                pass
            time.sleep(0.5)
        time.sleep(5.0)  # warm-up
        pids = {n: node_pid(n) for n in NODES}
        c0 = {n: process_cpu_seconds(p) for n, p in pids.items()}
        w0 = time.monotonic()
        print(f"[bench sensors] measuring {WALL:.0f} wall s at real-time factor 1 ...", flush=True)
        time.sleep(WALL)
        wall = time.monotonic() - w0
        c1 = {n: process_cpu_seconds(p) for n, p in pids.items()}
    per = {f"cpu_frac{n.replace('/', '_')}": (c1[n] - c0[n]) / wall for n in NODES}
    result = {"sensors_cpu_frac": sum(per.values()), **per, "wall_seconds": wall, "real_time_factor": 1.0,
              "scenario": "slalom at 3 m/s on flat ground (bench/data/slalom.csv); gps 5 Hz, imu 100 Hz, mag 50 Hz, 2 lasers 10 Hz, "
                          "cameras off; no subscribers to the adapters' outputs",
              "machine": machine(), "target_sensors_cpu_frac": 0.10}  # issue 11
    print(f"[bench sensors] simulator + adapters: {result['sensors_cpu_frac']:.3f} of one core", flush=True)
    write_result("sensors", result)


if __name__ == "__main__":
    main()
