"""The obstacle guard's configuration for the roscpp guard (``guard_cpp``), read and checked
by the same code as the Python guard's (:func:`quadrivio_navigation.ros.guard_node.guard_config`).

``python3 -m quadrivio_navigation.ros.guard_config --node /guard`` reads the private
parameters of node ``/guard`` (and ``/vehicle``, ``/scenario``, ``/site``, ``/run/seed``)
from the parameter server and writes on stdout, one item per line (floats as Python's
``repr``: exact)::

    param <name> <value>                      every numeric field of GuardParams
    scanner <topic> <frame> <covers> <no_return>
    zone <x> <y>                              the operating zone's vertices (map frame)
    body <front> <rear> <left> <right>        the vehicle's rectangle about base_link [m]
    vehicle <wheelbase> <ratio> <max_rate> <wheel_radius>
    tracks <front> <rear>                     the wheels' centres: (wheelbase, +-front/2), (0, +-rear/2)
    imu_rpy <roll> <pitch> <yaw>              the IMU's mount in base_link
    imu_xyz <x> <y> <z>                       ...and its position (the attitude's lever arm)
    node <name> <value>                       base_frame, request_timeout, ground_tolerance,
                                              ground_position_sigmas, ground_tolerance_max,
                                              ground_position_sd_min
    terrain <rows> <cols> <res> <x0> <y0>     then rows x cols float64 heights (row-major,
                                              little-endian, row index growing with y)
    end

A bad parameter ends it with status 1 and the reason on stderr (the C++ node then stops
with it). The node calls it once at start; it is not meant to be run by hand, but it can
be, to see what the guard will use.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from typing import BinaryIO

import numpy as np


def emit(out: BinaryIO, p, node, vehicle, hf) -> None:
    """Write the configuration (see the module docstring) to the binary stream ``out``."""
    from ..costmap import Footprint

    lines = []
    for f in dataclasses.fields(p):
        value = getattr(p, f.name)
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            lines.append(f"param {f.name} {float(value)!r}")
    for s in p.scanners:
        for text in (s.topic, s.frame, s.covers):
            if not text or any(c.isspace() for c in text):
                raise ValueError(f"scanner field {text!r} is empty or holds white space")
        lines.append(f"scanner {s.topic} {s.frame} {s.covers} {s.no_return}")
    for x, y in p.zone:
        lines.append(f"zone {float(x)!r} {float(y)!r}")
    body = Footprint.from_vehicle(vehicle, 0.0)
    lines.append(f"body {body.front!r} {body.rear!r} {body.left!r} {body.right!r}")
    st = vehicle.steering
    lines.append(f"vehicle {vehicle.wheelbase!r} {st.ratio!r} {st.max_rate!r} {vehicle.wheel_radius!r}")
    lines.append(f"tracks {vehicle.front_track!r} {vehicle.rear_track!r}")
    rpy = vehicle.sensors["imu_link"].rpy if "imu_link" in vehicle.sensors else (0.0, 0.0, 0.0)
    lines.append("imu_rpy " + " ".join(repr(float(a)) for a in rpy))
    xyz = vehicle.sensors["imu_link"].xyz if "imu_link" in vehicle.sensors else (0.0, 0.0, 0.0)
    lines.append("imu_xyz " + " ".join(repr(float(a)) for a in xyz))
    lines.append(f"node base_frame {node.base_frame}")
    lines.append(f"node request_timeout {node.request_timeout!r}")
    lines.append(f"node ground_tolerance {node.ground_tolerance!r}")
    lines.append(f"node ground_position_sigmas {node.ground_position_sigmas!r}")
    lines.append(f"node ground_tolerance_max {node.ground_tolerance_max!r}")
    lines.append(f"node ground_position_sd_min {node.ground_position_sd_min!r}")
    out.write(("\n".join(lines) + "\n").encode())
    if hf is not None:
        rows, cols = hf.z.shape
        out.write(f"terrain {rows} {cols} {hf.res!r} {hf.x0!r} {hf.y0!r}\n".encode())
        out.write(np.ascontiguousarray(hf.z, dtype="<f8").tobytes())
        out.write(b"\n")
    out.write(b"end\n")
    out.flush()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="guard_config", description=__doc__.split("\n\n")[0])
    ap.add_argument("--node", required=True, help="the guard node's resolved name (its private namespace)")
    args = ap.parse_args(argv)
    import rospy

    from .guard_node import guard_config

    name = "/" + args.node.strip("/")
    private = rospy.get_param(name, {})  # rospy reaches the parameter server without a node
    private = {k: v for k, v in private.items() if k != "lockstep"} if isinstance(private, dict) else {}
    out, sys.stdout = sys.stdout, sys.stderr  # whatever is printed or logged meanwhile stays off the protocol
    try:
        p, node, vehicle, hf = guard_config(private, name)
    finally:
        sys.stdout = out
    emit(out.buffer, p, node, vehicle, hf)
    return 0


if __name__ == "__main__":
    sys.exit(main())
