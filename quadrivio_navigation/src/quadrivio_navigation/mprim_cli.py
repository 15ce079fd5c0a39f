"""``rosrun quadrivio_navigation generate_mprim --resolution 0.2 --out quadrivio.mprim``

Motion primitives for the vehicle of ``vehicle.yaml`` (its minimum turning radius) at a
map's resolution, written in SBPL's ``.mprim`` format, with a plot of them next to the
file (``.png``). Load them with the planner's ``lattice/mprim_file`` parameter, or bring
primitives of your own in the same format: the planner checks that their resolution
matches the map and that no primitive turns tighter than the vehicle can.

Exit status 0, or 2 on bad input.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from typing import List, Optional

from quadrivio_config import ConfigError
from quadrivio_description.vehicle import load_vehicle
from quadrivio_runtime.files import atomic_path

from .mprim import GenerationParams, PrimitiveSet, check_for_vehicle, generate, write_mprim


def plot(ps: PrimitiveSet, path: str, radius: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 5.5))
    for ax, ks in zip(axes, (range(ps.headings), [0, 1, 2])):
        for p in ps.primitives:
            if p.start_heading in ks:
                colour = "tab:red" if p.reverse else "tab:blue"
                ax.plot(p.poses[:, 0], p.poses[:, 1], "-", color=colour, lw=0.8)
                ax.plot(p.dx * ps.resolution, p.dy * ps.resolution, ".", color=colour, ms=3)
        ax.set_aspect("equal")
        ax.grid(True, lw=0.3)
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
    axes[0].set_title(f"all {len(ps.primitives)} primitives, {ps.headings} headings")
    axes[1].set_title("start headings 0-2 (forward blue, reverse red)")
    fig.suptitle(f"{ps.resolution} m cells, turning radius {radius:.2f} m", fontsize=10)
    fig.tight_layout()
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    plt.close(fig)


def main(argv: Optional[List[str]] = None) -> int:
    ap = argparse.ArgumentParser(prog="generate_mprim", description=__doc__.split("\n\n")[0])
    ap.add_argument("--resolution", type=float, required=True, help="the map's cell size [m]")
    ap.add_argument("--out", required=True, help=".mprim file to write")
    ap.add_argument("--headings", type=int, default=16)
    ap.add_argument("--no-reverse", action="store_true", help="forward primitives only")
    ap.add_argument("--reverse-cost", type=int, default=3, help="cost multiplier of reverse primitives")
    ap.add_argument("--long-step", type=float, default=2.0, help="nominal length of the long straight [m]")
    ap.add_argument("--radius-margin", type=float, default=1.05, help="turning radius x this (as the planner)")
    ap.add_argument("--vehicle", default="", help="vehicle YAML (default: quadrivio_description's)")
    args = ap.parse_args([a for a in (argv if argv is not None else sys.argv[1:]) if ":=" not in a])
    try:
        if not (args.resolution > 0 and math.isfinite(args.resolution)):
            raise ConfigError(f"--resolution {args.resolution}: must be a positive size in metres")
        if not 4 <= args.headings <= 64:
            raise ConfigError(f"--headings {args.headings}: must be between 4 and 64")
        if args.reverse_cost < 1:
            raise ConfigError(f"--reverse-cost {args.reverse_cost}: must be at least 1")
        if not (args.long_step > 0 and args.radius_margin >= 1.0):
            raise ConfigError("--long-step must be positive and --radius-margin at least 1")
        vehicle = load_vehicle(args.vehicle)
        radius = vehicle.min_turning_radius * args.radius_margin
        ps = generate(GenerationParams(radius, args.resolution, args.headings, not args.no_reverse,
                                       args.reverse_cost, args.long_step))
        check_for_vehicle(ps, vehicle.min_turning_radius, args.resolution)
    except ConfigError as exc:
        print(f"generate_mprim: {exc}", file=sys.stderr)
        return 2
    folder = os.path.dirname(os.path.abspath(args.out))
    os.makedirs(folder, exist_ok=True)
    write_mprim(ps, args.out)
    png = os.path.splitext(args.out)[0] + ".png"
    plot(ps, png, radius)
    print(f"[generate_mprim] {len(ps.primitives)} primitives, {ps.headings} headings, {args.resolution} m cells, "
          f"turning radius {radius:.2f} m: {args.out}, {png}")
    return 0
