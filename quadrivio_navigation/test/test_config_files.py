"""Every config/*.yaml of quadrivio_navigation states the defaults of the dataclasses that
read it (and nothing else): the file is the documentation of the defaults. (The nodes'
own parameter classes live in their ROS wiring; importing them needs no master.)"""
import os

import pytest
import yaml

from quadrivio_config import from_mapping
from quadrivio_navigation.follower import FollowerConfig
from quadrivio_navigation.guard import GuardParams
from quadrivio_navigation.local_layer import LocalLayerParams
from quadrivio_navigation.maps import MapParams
from quadrivio_navigation.paths import PathParams
from quadrivio_navigation.planning import PlannerParams
from quadrivio_navigation.rollover import RolloverParams
from quadrivio_navigation.ros.planner_node import NodeParams as PlannerNodeParams
from quadrivio_navigation.ros.guard_node import NodeParams as GuardNodeParams
from quadrivio_navigation.ros.local_layer_node import NodeParams as LayerNodeParams
from quadrivio_navigation.ros.rollover_node import NodeParams as RolloverNodeParams

CONFIG = os.path.join(os.path.dirname(__file__), "..", "config")


@pytest.mark.parametrize("name, classes", [
    ("planner.yaml", (PlannerParams, PlannerNodeParams)),
    ("follower.yaml", (FollowerConfig,)),
    ("path.yaml", (PathParams,)),
    ("map_server.yaml", (MapParams,)),
    ("rollover.yaml", (RolloverParams, RolloverNodeParams)),
    ("guard.yaml", (GuardParams, GuardNodeParams)),
    ("local_layer.yaml", (LocalLayerParams, LayerNodeParams)),
])
def test_config_file_states_the_defaults(name, classes):
    import dataclasses

    with open(os.path.join(CONFIG, name)) as fh:
        data = yaml.safe_load(fh)
    rest = dict(data)
    for cls in classes:
        keys = {f.name for f in dataclasses.fields(cls)}
        mine = {k: v for k, v in rest.items() if k in keys}
        for k in mine:
            rest.pop(k)
        assert from_mapping(cls, mine, name) == cls(), f"{name} disagrees with {cls.__name__}'s defaults"
    assert not rest, f"{name} has keys no class reads: {sorted(rest)}"
