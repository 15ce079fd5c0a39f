"""Actors (quadrivio_sim.actors) and the simulator's contacts: motion along waypoints,
triggers, bad definitions named, bodies the lasers see and the vehicle hits."""
import math

import pytest

from quadrivio_config import ConfigError
from quadrivio_sim.actors import ActorMotion, load_actors


def one(**kw):
    base = {"name": "p", "waypoints": [[0.0, 0.0], [10.0, 0.0]]}
    base.update(kw)
    return load_actors([base], "test")[0]


def test_once_walks_the_waypoints_then_stands():
    m = ActorMotion(one(speed=2.0, start_time=1.0))
    p = m.update(0.5, (100.0, 100.0))
    assert (p.x, p.y, p.speed) == (0.0, 0.0, 0.0)
    p = m.update(3.0, (100.0, 100.0))
    assert p.x == pytest.approx(4.0) and p.speed == 2.0 and p.yaw == pytest.approx(0.0)
    p = m.update(10.0, (100.0, 100.0))
    assert (p.x, p.speed) == (10.0, 0.0)


def test_loop_and_back_and_forth():
    sq = [[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]]
    m = ActorMotion(one(waypoints=sq, speed=1.0, mode="loop"))
    assert (m.pose(6.0).x, m.pose(6.0).y) == pytest.approx((4.0, 2.0))
    assert m.pose(6.0).yaw == pytest.approx(math.pi / 2)
    assert (m.pose(16.0 + 1.0).x, m.pose(17.0).y) == pytest.approx((1.0, 0.0))  # round again
    m = ActorMotion(one(speed=2.0, mode="back_and_forth"))
    assert m.pose(7.0).x == pytest.approx(6.0) and m.pose(7.0).yaw == pytest.approx(math.pi)  # on the way back
    assert m.pose(21.0).x == pytest.approx(2.0)


def test_trigger_waits_for_the_vehicle():
    m = ActorMotion(one(speed=1.0, trigger_distance=5.0, start_time=2.0))
    for t in (0.0, 10.0, 20.0):
        assert m.update(t, (50.0, 0.0)).speed == 0.0  # far away: stands
    assert m.update(21.0, (4.0, 0.0)).speed == 0.0  # triggered at 21 s: starts 2 s later
    assert m.triggered_at == 21.0
    assert m.update(24.0, (4.0, 0.0)).x == pytest.approx(1.0)


@pytest.mark.parametrize("bad,words", [
    ({"waypoints": []}, "at least one"),
    ({"mode": "loop"}, "three waypoints"),
    ({"mode": "back_and_forth", "waypoints": [[0, 0]]}, "at least two"),
    ({"size": [1.0, 2.0]}, "size"),
    ({"kind": "dragon"}, "kind"),
    ({"speed": -1.0}, "speed"),
    ({"waypoints": [[0, "x"]]}, "waypoints"),
])
def test_bad_actors_are_named(bad, words):
    with pytest.raises(ConfigError, match=words):
        one(**bad)


def test_names_must_be_unique():
    with pytest.raises(ConfigError, match="unique: p"):
        load_actors([{"name": "p", "waypoints": [[0, 0]]}, {"name": "p", "waypoints": [[1, 1]]}], "test")
    with pytest.raises(ConfigError, match="list"):
        load_actors({"name": "p"}, "test")


def test_the_vehicle_hits_a_person_the_lasers_see():
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.script import ScriptRow, SetpointScript
    from test_sim_core import default_params
    from quadrivio_sim.simulator import Simulator

    vehicle = load_vehicle()
    actuators = load_actuators(package_file("config", "actuators.yaml"))

    actors = [{"name": "bob", "kind": "person", "waypoints": [[8.0, 0.0]]},
              {"name": "walker", "kind": "person", "waypoints": [[4.0, 6.0], [4.0, 12.0]], "speed": 1.0}]
    sim = Simulator(default_params(actors=actors), vehicle, actuators, build_urdf(vehicle))
    sim.script = SetpointScript([ScriptRow(0.0, 2.0, 0.0, 0.0)])
    first = None
    contacts, seen = [], []
    while sim.t < 6.0:
        for name, s in sim.step():
            if name == "contact":
                contacts.append(s)
            if name == "scan" and s.frame == "laser_front" and first is None:
                first = min(s.ranges)
            if name == "actors":
                seen.append(s)
    # the front laser (1.6 m ahead of base_link) sees bob's near side: 8 - 0.3 - 1.6
    assert first == pytest.approx(8.0 - 0.3 - 1.6, abs=0.05)
    assert len(contacts) == 1
    c = contacts[0]
    assert c.body == "bob" and c.kind == "person"
    assert c.speed == pytest.approx(2.0, abs=0.3)
    # the walker moved 1 m/s along its waypoints (ground truth at 10 Hz)
    last = {a.name: a for a in seen[-1]}
    assert last["walker"].y == pytest.approx(6.0 + min(sim.t, 6.0), abs=0.15)
    assert last["bob"].x == 8.0 and last["bob"].speed == 0.0
