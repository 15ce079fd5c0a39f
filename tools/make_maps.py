#!/usr/bin/env python3
"""Write the scenarios' maps (scenarios/maps/*.yaml + .pgm) from their generators in
quadrivio_navigation.synthetic_maps, so that they can be regenerated and reviewed.

    python3 tools/make_maps.py            # with env.sh sourced
"""
import os

from quadrivio_navigation.maps import save_map
from quadrivio_navigation.synthetic_maps import orchard, scattered, yard

ROOT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..")
OUT = os.path.join(ROOT, "scenarios", "maps")

MAPS = {
    # 6 rows of trees 5 m apart, 39 m long, headlands of 10 m and 9 m, at 0.2 m
    "orchard": lambda: orchard(seed=3),
    # 100 m x 100 m, rocks and buildings, the start and goal areas of scenarios/field.yaml kept clear
    "field": lambda: scattered(size=100.0, res=0.2, seed=7, rocks=70, buildings=9,
                               clear=((-38.0, -38.0, 5.0), (35.0, 32.0, 5.0))),
    # the planner's node test and the end-to-end rostest: a blind alley and a closed pen
    "../../quadrivio_navigation/test/data/yard": yard,
}

if __name__ == "__main__":
    os.makedirs(OUT, exist_ok=True)
    for name, make in MAPS.items():
        path = save_map(make(), os.path.normpath(os.path.join(OUT, f"{name}.yaml")))
        print(f"wrote {os.path.relpath(path)}")
