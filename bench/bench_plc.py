"""Benchmark: PLCClient <-> emulated PLC round trip on loopback.

The simulated vehicle (sim.launch without localization and navigation: simulator with
the emulated PLC, sensor adapters, PLCClient) runs a 10-minute simulated drive at real-time factor 5 (2 wall
minutes) while a driver node sends autonomous setpoints at 50 Hz. The PLCClient
measures the time from each frame it sends to the PLC's ACK (wall clock) and counts
lost frames (gaps in the PLC's sequence numbers), frames never acknowledged and bad
frames on both ends; the figures come from its /diagnostics and the simulator's.

Keys: plc_rtt_p50_ms, plc_rtt_p99_ms, plc_rtt_max_ms, plc_frames_sent, plc_dropped_frames.
Writes bench/results/plc.json.
"""
import math
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from common import machine, ros_session, write_result  # noqa: E402

SIM_SECONDS = 600.0
RTF = 5.0


def diag_values(status):
    return {kv.key: kv.value for kv in status.values}


def main():
    with ros_session() as ros:
        scenario = os.path.join(os.path.dirname(HERE), "test", "scenarios", "quiet.yaml")
        # The link alone: no follower fighting the driver's setpoints, no smoother
        # competing for the 2 cores at 5x real time.
        ros.launch("quadrivio", "sim.launch", f"rtf:={RTF}", f"scenario_file:={scenario}", "navigation:=false",
                   "localization:=false")
        import rospy
        from diagnostic_msgs.msg import DiagnosticArray
        from quadrivio_plc.msg import Setpoint
        from quadrivio_plc.srv import SetMode

        ros.init_node("bench_plc")
        latest = {}
        rospy.Subscriber("/diagnostics", DiagnosticArray,
                         lambda m: latest.update({s.name: s for s in m.status}), queue_size=100)
        rospy.wait_for_service("/plc_client/set_mode", timeout=120)
        # the link is up: a state frame of the PLC's (without a session the client says so on
        # vehicle/state at 10 Hz, plc_time NaN; AUTO asked for then is refused)
        from quadrivio_plc.msg import VehicleState

        deadline = time.monotonic() + 120.0
        while not math.isfinite(rospy.wait_for_message("/vehicle/state", VehicleState, timeout=120).plc_time):
            if time.monotonic() > deadline:
                raise RuntimeError("no state frame from the PLC within 120 s")
        ok = rospy.ServiceProxy("/plc_client/set_mode", SetMode)(4)
        if not ok.success:
            raise RuntimeError(f"could not enter AUTO: {ok.message}")
        pub = rospy.Publisher("/vehicle/setpoint/auto", Setpoint, queue_size=10)

        def tick(_):
            m = Setpoint()
            m.header.stamp = rospy.Time.now()
            t = m.header.stamp.to_sec()
            m.speed, m.handlebar = 2.0, 0.25 * math.sin(0.05 * t)
            pub.publish(m)
        rospy.Timer(rospy.Duration(0.02), tick)
        t0 = rospy.get_time()
        last_report = 0.0
        while rospy.get_time() < t0 + SIM_SECONDS:
            time.sleep(0.5)
            done = rospy.get_time() - t0
            if done - last_report >= 60.0:
                print(f"[bench plc] {done:.0f} / {SIM_SECONDS:.0f} sim s", flush=True)
                last_report = done
        time.sleep(2.5)  # one more diagnostics period
        client = diag_values(next(s for n, s in latest.items() if n.endswith("PLC link")))
        server = diag_values(next(s for n, s in latest.items() if n.endswith("emulated PLC")))
    dropped = (int(client["lost frames"]) + int(client["frames never acknowledged"]) + int(client["bad frames"])
               + int(server["bad frames"]) + int(server["stale frames (sequence did not advance)"])
               + int(client["disconnects"]))
    result = {
        "plc_rtt_p50_ms": float(client["rtt p50 [ms]"]),
        "plc_rtt_p99_ms": float(client["rtt p99 [ms]"]),
        "plc_rtt_max_ms": float(client["rtt max [ms]"]),
        "plc_rtt_samples": int(client["rtt samples"]),
        "plc_frames_sent": int(client["frames sent"]),
        "plc_frames_received": int(client["frames received"]),
        "plc_dropped_frames": dropped,
        "sim_seconds": SIM_SECONDS, "real_time_factor": RTF,
        "scenario": "sim.launch, quiet scenario, autonomous setpoints at 50 Hz (2 m/s slalom)",
        "machine": machine(), "target_plc_rtt_p99_ms": 2.0,
    }
    print(f"[bench plc] rtt p50 {result['plc_rtt_p50_ms']:.3f} ms, p99 {result['plc_rtt_p99_ms']:.3f} ms over "
          f"{result['plc_rtt_samples']} frames; dropped {dropped}", flush=True)
    write_result("plc", result)


if __name__ == "__main__":
    main()
