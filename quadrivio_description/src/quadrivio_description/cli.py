"""``generate_urdf``: print (or write) the URDF generated from a vehicle parameter file."""

from __future__ import annotations

import argparse
import sys
from typing import List, Optional

from quadrivio_config import ConfigError
from .urdf import build_urdf
from .vehicle import default_vehicle_file, load_vehicle, scenario_vehicle


def generate_urdf_main(argv: Optional[List[str]] = None) -> int:
    parser = argparse.ArgumentParser(
        prog="generate_urdf", description="Generate the Quadrivio URDF from a vehicle parameter YAML.")
    parser.add_argument("vehicle", nargs="?", default="",
                        help=f"vehicle parameter file (default: {default_vehicle_file()})")
    parser.add_argument("--scenario", default="",
                        help="apply this scenario file's vehicle: overrides (drive train, masses, limits)")
    parser.add_argument("--out", default="", help="write the URDF here instead of standard output")
    parser.add_argument("--no-root-inertia", action="store_true",
                        help="leave out base_link's <inertial> (for robot_state_publisher: KDL ignores it)")
    # roslaunch appends __name:= / __log:= when run as a node; ignore ROS remapping arguments.
    args = parser.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    try:
        vehicle = load_vehicle(args.vehicle)
        if args.scenario:
            vehicle = scenario_vehicle(args.scenario, vehicle)
        text = build_urdf(vehicle, root_inertia=not args.no_root_inertia)
    except ConfigError as exc:
        print(f"generate_urdf: {exc}", file=sys.stderr)
        return 1
    if args.out:
        with open(args.out, "w", encoding="utf-8") as fh:
            fh.write(text)
    else:
        sys.stdout.write(text)
    return 0
