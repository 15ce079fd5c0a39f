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


def simulator_with(actors, speed=0.0, brake=0.0):
    """The simulator core with these actors, driving straight at ``speed`` (``brake`` on)."""
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle
    from quadrivio_sim.actuators import load_actuators
    from quadrivio_sim.paths import package_file
    from quadrivio_sim.script import ScriptRow, SetpointScript
    from test_sim_core import default_params
    from quadrivio_sim.simulator import Simulator

    vehicle = load_vehicle()
    sim = Simulator(default_params(actors=actors), vehicle, load_actuators(package_file("config", "actuators.yaml")),
                    build_urdf(vehicle))
    sim.script = SetpointScript([ScriptRow(0.0, speed, 0.0, brake)])
    return sim


def test_the_vehicle_hits_a_person_the_lasers_see():
    actors = [{"name": "bob", "kind": "person", "waypoints": [[8.0, 0.0]]},
              {"name": "walker", "kind": "person", "waypoints": [[4.0, 6.0], [4.0, 12.0]], "speed": 1.0}]
    sim = simulator_with(actors, speed=2.0)
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


def test_an_actor_held_back_waits_where_it_is_and_walks_on_later_by_the_wait():
    m = ActorMotion(one(speed=1.0))
    for k in range(11):  # 0.0 .. 1.0 s: at 1 m
        m.update(0.1 * k, (100.0, 100.0))
    for k in range(11, 16):  # 1.1 .. 1.5 s: every step taken back
        m.update(0.1 * k, (100.0, 100.0))
        p = m.hold_back()
        assert (p.x, p.speed) == (pytest.approx(1.0), 0.0) and m.waiting
    p = m.update(2.0, (100.0, 100.0))  # walks on: 0.5 s of walking since, not 1.0
    assert p.x == pytest.approx(1.5) and p.speed == 1.0 and not m.waiting
    assert m.held == pytest.approx(0.5)


def test_a_person_walking_into_the_standing_vehicles_side_waits_beside_it():
    """Seen on a worker walking up and down an orchard lane while the vehicle stood in it:
    moved kinematically into the vehicle, the body shoved 390 kg round by 90 deg (25
    contacts, the estimate's heading 100 deg off). A person stops short of a vehicle: here
    they wait keep_clear from its body, nothing is touched, the vehicle stays where it
    stood, and one walking along its side passes."""
    actors = [{"name": "into", "kind": "person", "waypoints": [[0.6, 5.0], [0.6, -5.0]], "speed": 1.0},
              {"name": "along", "kind": "person", "waypoints": [[-4.0, -1.4], [6.0, -1.4]], "speed": 1.0}]
    sim = simulator_with(actors, brake=1.0)  # braked, standing
    start = None
    contacts, seen = [], []
    while sim.t < 12.0:
        for name, s in sim.step():
            if name == "contact":
                contacts.append(s)
            if name == "actors":
                seen.append({a.name: a for a in s})
        if start is None and sim.t >= 1.0:
            start = sim.world.base_state()[0]
    assert contacts == []
    end = sim.world.base_state()[0]
    assert math.hypot(end[0] - start[0], end[1] - start[1]) < 0.01
    into, along = sim.actors[0], sim.actors[1]
    assert into.waiting and into.held > 5.0 and into.last.x == pytest.approx(0.6)
    gap = sim.world.actor_gap(0, 1.0)
    assert 0.2 <= gap < 0.22  # within a step of keep_clear (1 m/s)
    assert seen[-1]["into"].speed == 0.0
    # the one walking along the side, 1.4 m from base_link's centre line, went by
    assert along.last.x == pytest.approx(6.0) and along.held == 0.0
    # the control arm: an actor blind to the vehicle (the gap never found) walks into it
    sim = simulator_with(actors[:1], brake=1.0)
    sim.world.actor_gap = lambda k, within: math.inf
    while sim.t < 12.0:
        for name, s in sim.step():
            if name == "contact":
                contacts.append(s)
    assert contacts and contacts[0].body == "into"


def _drive_past(y_person, enable_spheres=False):
    """Contacts of the vehicle driving straight at 1 m/s past a person standing at (5, y)."""
    sim = simulator_with([{"name": "bystander", "kind": "person", "waypoints": [[5.0, y_person]]}], speed=1.0)
    if enable_spheres:  # the wheels' ground spheres meeting the person too, as before
        for j in sim.world.wheels:
            sim.world.pb.setCollisionFilterPair(sim.world.robot, sim.world.actor_ids[0][0], j, -1, 1)
    contacts = []
    while sim.t < 9.0:
        contacts += [s for name, s in sim.step() if name == "contact"]
    return contacts


def test_the_vehicle_touches_what_its_tyres_touch_not_what_the_wheels_spheres_reach():
    """The wheels meet the ground as spheres of the tyre's radius, which reach 0.19 m past
    the tyres' outer faces sideways; a person 0.17 m from the side of a passing vehicle was
    touched by one. Now the tyres meet everything but the ground as what they are."""
    contacts = _drive_past(-(0.5 * vehicle_width() + 0.10 + 0.3))
    assert contacts == []  # 0.10 m beside the tyres: passed
    contacts = _drive_past(-(0.5 * vehicle_width() + 0.10 + 0.3), enable_spheres=True)
    assert contacts and {c.body for c in contacts} == {"bystander"}  # the control arm: the spheres reach them
    contacts = _drive_past(-(0.5 * vehicle_width() - 0.05 + 0.3))
    assert contacts and {c.body for c in contacts} == {"bystander"}  # 0.05 m inside the tyres' outer face: hit


def vehicle_width():
    from quadrivio_description.vehicle import load_vehicle

    return load_vehicle().body.width
