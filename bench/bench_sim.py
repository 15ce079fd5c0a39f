"""Benchmark: the simulator alone, one ATV, default physics step, headless.

Two figures:

* ``sim_core_rtf`` / ``sim_core_cpu_s_per_sim_s``: the simulator core (physics, PLC
  loops, every layer-1 sensor at its default rate, cameras off) stepped as fast as
  possible in this process, driving a slalom so contacts and steering are exercised;
* ``sim_rtf`` / ``sim_cpu_s_per_sim_s``: the simulator *node* at real_time_factor 0
  under a ROS master, publishing /clock, ground truth, TF, joint states and every
  layer-1 topic, measured from /clock against wall time and from the node's CPU time.

Writes bench/results/sim.json.
"""
import os
import sys
import time

from quadrivio_config import from_mapping, load_yaml
from quadrivio_description.urdf import build_urdf
from quadrivio_description.vehicle import load_vehicle
from quadrivio_sim.actuators import load_actuators
from quadrivio_sim.paths import package_file
from quadrivio_sim.script import load_script
from quadrivio_sim.simulator import SimParams, Simulator

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, node_cpu_seconds, ros_session, write_result  # noqa: E402

SIM_SECONDS = 120.0


SCRIPT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data", "slalom.csv")


def bench_core():
    vehicle = load_vehicle()
    params = from_mapping(SimParams, load_yaml(package_file("config", "sim.yaml")), "sim.yaml")
    sim = Simulator(params, vehicle, load_actuators(package_file("config", "actuators.yaml")), build_urdf(vehicle))
    sim.script = load_script(SCRIPT)
    while sim.t < 2.0:
        sim.step()
    w0, c0, t0 = time.perf_counter(), time.process_time(), sim.t
    samples = 0
    while sim.t < t0 + SIM_SECONDS:
        samples += len(sim.step())
    wall, cpu = time.perf_counter() - w0, time.process_time() - c0
    sim.close()
    return {"sim_core_rtf": SIM_SECONDS / wall, "sim_core_cpu_s_per_sim_s": cpu / SIM_SECONDS,
            "sim_core_step_us": wall / (SIM_SECONDS / params.physics.dt) * 1e6,
            "sim_core_samples_per_sim_s": samples / SIM_SECONDS, "physics_dt_s": params.physics.dt}


def bench_node():
    script = SCRIPT
    with ros_session() as ros:
        ros.launch("quadrivio_sim", "bench_simulator.launch", f"script_file:={script}", "rtf:=0")
        import rospy
        from rosgraph_msgs.msg import Clock

        ros.init_node("bench_sim")
        stamps = []
        sub = rospy.Subscriber("/clock", Clock, lambda m: stamps.append((time.perf_counter(), m.clock.to_sec())),
                               queue_size=100000)
        deadline = time.perf_counter() + 300
        while (not stamps or stamps[-1][1] < 2.0) and time.perf_counter() < deadline:
            time.sleep(0.05)
        w0, s0 = stamps[-1]
        c0 = node_cpu_seconds("/simulator")
        while stamps[-1][1] < s0 + SIM_SECONDS and time.perf_counter() < deadline:
            time.sleep(0.05)
        w1, s1 = stamps[-1]
        c1 = node_cpu_seconds("/simulator")
        sub.unregister()
    return {"sim_rtf": (s1 - s0) / (w1 - w0), "sim_cpu_s_per_sim_s": (c1 - c0) / (s1 - s0)}


def main():
    print("[bench sim] core: %g sim s as fast as possible ..." % SIM_SECONDS, flush=True)
    result = bench_core()
    print("[bench sim] core rtf %.1f" % result["sim_core_rtf"], flush=True)
    print("[bench sim] node at real_time_factor 0 under a ROS master ...", flush=True)
    result.update(bench_node())
    print("[bench sim] node rtf %.1f, %.3f CPU s per sim s" % (result["sim_rtf"], result["sim_cpu_s_per_sim_s"]),
          flush=True)
    result.update({"machine": machine(), "sim_seconds": SIM_SECONDS, "scenario": "slalom at 3 m/s, flat ground",
                   "sensors": "gps 5 Hz, imu 100 Hz, mag 50 Hz, 2 lasers 10 Hz x 271 rays, cameras off",
                   "target_sim_rtf": 30.0})
    write_result("sim", result)


if __name__ == "__main__":
    main()
