"""The simulator's lockstep decisions (quadrivio_sim.lockstep), ROS-free."""

from quadrivio_runtime.lockstep_wire import ACK_TOPIC, PLC, STATE_TOPIC, member_names
from quadrivio_sim.lockstep import Coordinator


def report(node, seq=0, sent=None, subs=None, pubs=None, next_timer=None, **extra):
    r = {"node": node, "seq": seq, "sent": sent or {}, "subs": subs or {}, "pubs": pubs or {},
         "next_timer": next_timer, "error": ""}
    r.update(extra)
    return r


def test_members_are_the_nodes_marked_in_the_parameter_tree():
    tree = {"lockstep": {"enabled": True}, "follower": {"lockstep": True, "rate": 50.0},
            "gps": {"nmea_gps": {"lockstep": False}}, "sim": {"imu_adapter": {"lockstep": True}},
            "vehicle": {"mass": 390.0}}
    assert member_names(tree) == ["/follower", "/sim/imu_adapter"]


def test_a_report_from_a_stranger_or_an_older_round_is_ignored():
    c = Coordinator(["/a"], "/simulator")
    assert not c.on_report(report("/intruder", 5))
    assert c.on_report(report("/a", 5, sent={"/x": 3}))
    c.on_report(report("/a", 4, sent={"/x": 1}))
    assert c.reports["/a"]["sent"] == {"/x": 3}
    assert c.pending(["/a"], 5) == [] and c.pending(["/a"], 6) == ["/a"]


def test_the_watermark_names_every_member_publisher_even_before_it_sent_anything():
    # A subscriber treats a publisher missing from the watermark as outside the lockstep
    # and hands its messages over at once: a member that has not published yet must be there.
    c = Coordinator(["/a", "/b"], "/simulator")
    c.on_report(report("/a", sent={"/x": 2}, pubs={"/x": 1, "/y": 0}))
    c.on_report(report("/b", pubs={"/z": 1}))
    wm = c.watermark({"/sim/imu": 7}, (4, 1))
    assert wm["/x"] == {"/a": 2} and wm["/y"] == {"/a": 0} and wm["/z"] == {"/b": 0}
    assert wm["/sim/imu"] == {"/simulator": 7}
    assert wm[STATE_TOPIC] == {PLC: 4} and wm[ACK_TOPIC] == {PLC: 1}


def test_a_round_names_only_the_members_with_something_new_or_a_timer_due():
    c = Coordinator(["/adapter", "/loc", "/idle"], "/simulator")
    c.on_report(report("/adapter", subs={"/sim/imu": 1}, pubs={"/imu/data": 1}, next_timer=20_000_000))
    c.on_report(report("/loc", subs={"/imu/data": 1}, next_timer=50_000_000))
    c.on_report(report("/idle", subs={"/scan": 1}))
    wm = c.watermark({"/sim/imu": 1}, (0, 0))
    assert c.needing(wm) == ["/adapter"]
    c.sent_round(["/adapter"], wm)
    assert c.needing(wm) == []  # handled: nothing new until someone publishes
    c.on_report(report("/adapter", seq=1, sent={"/imu/data": 1}, subs={"/sim/imu": 1}, pubs={"/imu/data": 1},
                       next_timer=20_000_000))
    assert c.needing(c.watermark({"/sim/imu": 1}, (0, 0))) == ["/loc"]
    assert c.timers_due(10_000_000) == [] and c.timers_due(20_000_000) == ["/adapter"]
    assert c.timers_due(50_000_000) == ["/adapter", "/loc"]


def test_the_plc_link_needs_the_client_when_frames_were_sent():
    c = Coordinator(["/plc_client"], "/simulator")
    c.on_report(report("/plc_client", subs={STATE_TOPIC: 1, ACK_TOPIC: 1}, link={"sent": 3}))
    assert c.needing(c.watermark({}, (0, 0))) == []
    assert c.needing(c.watermark({}, (1, 0))) == ["/plc_client"]
    assert c.link_sent() == 3


def test_start_waits_for_every_member_and_every_connection():
    c = Coordinator(["/adapter", "/loc", "/plc_client"], "/simulator")
    c.on_report(report("/adapter", subs={"/sim/imu": 0}, pubs={"/imu/data": 1}))
    c.on_report(report("/loc", subs={"/imu/data": 1}))
    assert c.missing() == ["/plc_client"]
    blocked = c.not_connected({"/sim/imu": 1}, plc_session=False)
    assert blocked == ["/adapter <- /sim/imu (0 of 1 publishers)"]
    c.on_report(report("/adapter", seq=1, subs={"/sim/imu": 1}, pubs={"/imu/data": 1}))
    c.on_report(report("/plc_client", subs={STATE_TOPIC: 0, ACK_TOPIC: 0}))
    assert c.missing() == []
    assert c.not_connected({"/sim/imu": 1}, plc_session=False) == [
        f"/plc_client <- {ACK_TOPIC} (0 of 1 publishers)", f"/plc_client <- {STATE_TOPIC} (0 of 1 publishers)"]
    c.on_report(report("/plc_client", seq=1, subs={STATE_TOPIC: 1, ACK_TOPIC: 1}))
    assert c.not_connected({"/sim/imu": 1}, plc_session=True) == []
    # a topic two members publish needs both connections
    c.on_report(report("/loc", seq=1, subs={"/imu/data": 1}, pubs={"/imu/data": 1}))
    assert c.not_connected({"/sim/imu": 1}, plc_session=True) == ["/loc <- /imu/data (1 of 2 publishers)"]


def test_the_fingerprint_moves_with_the_counts():
    c = Coordinator(["/a"], "/simulator")
    c.on_report(report("/a", sent={"/x": 1}))
    f1 = c.fingerprint()
    c.on_report(report("/a", seq=1, sent={"/x": 1}))
    assert c.fingerprint() == f1
    c.on_report(report("/a", seq=2, sent={"/x": 2}))
    assert c.fingerprint() != f1


def test_start_waits_for_the_publishers_side_of_each_connection_too():
    # rospy lists a subscriber's connection before the handshake: what the publisher sends
    # before it has the connection is lost, and the round that waits for it never ends
    c = Coordinator(["/mag_adapter"], "/simulator")
    c.on_report(report("/mag_adapter", subs={"/sim/mag": 1}))
    assert c.not_connected({"/sim/mag": 0}, plc_session=True) == ["/simulator -> /sim/mag (0 of 1 subscribers)"]
    assert c.not_connected({"/sim/mag": 2}, plc_session=True) == []  # a recorder too: more is fine


def test_a_python_publisher_must_name_every_member_subscriber_and_the_clock_reach_every_member():
    # A recorder's connection must not stand in for a member's; and a member whose /clock
    # connection is not there yet would miss the first ticks and wait for a time that
    # never comes
    c = Coordinator(["/imu", "/loc", "/rollover"], "/simulator")
    c.on_report(report("/imu", pubs={"/imu/data": ["/loc", "/record_1"]}))
    c.on_report(report("/loc", subs={"/imu/data": 1}))
    c.on_report(report("/rollover", subs={"/imu/data": 1}))
    assert c.not_connected({"/clock": ["/imu", "/loc", "/record_1"]}, plc_session=True) == [
        "/simulator -> /clock (not yet to /rollover)", "/imu -> /imu/data (not yet to /rollover)"]
    c.on_report(report("/imu", seq=1, pubs={"/imu/data": ["/loc", "/record_1", "/rollover"]}))
    assert c.not_connected({"/clock": ["/imu", "/loc", "/rollover"]}, plc_session=True) == []


def test_an_ack_alone_names_no_one_its_next_round_waits_for_it():
    # The client handles ACK frames on arrival; the round that would only wait for one is
    # left out. The watermark still counts them, so the client's next round waits for them.
    c = Coordinator(["/plc_client"], "/simulator")
    c.on_report(report("/plc_client", subs={STATE_TOPIC: 1, ACK_TOPIC: 1, "/cmd/guarded": 1}))
    c.sent_round(["/plc_client"], c.watermark({}, (0, 0)))
    wm = c.watermark({}, (0, 2))
    assert c.needing(wm) == [] and wm[ACK_TOPIC] == {PLC: 2}
    wm = c.watermark({}, (1, 2))  # a STATE frame: a round, whose watermark holds both ACKs
    assert c.needing(wm) == ["/plc_client"] and wm[ACK_TOPIC] == {PLC: 2}


def test_only_members_that_only_the_simulator_feeds_run_their_timers_in_the_first_round():
    c = Coordinator(["/adapters", "/loc", "/plc_client", "/map_server", "/selfish"], "/simulator")
    c.on_report(report("/adapters", subs={"/sim/imu": 1, "/sim/gps": 1}, pubs={"/imu/data": 2, "/gps/fix": 1}))
    c.on_report(report("/loc", subs={"/imu/data": 1, "/gps/fix": 1}, pubs={"/odom": 1}))
    c.on_report(report("/plc_client", subs={STATE_TOPIC: 1, ACK_TOPIC: 1}))  # PLC frames come in rounds
    c.on_report(report("/map_server", subs={}, pubs={"/map": 1}))  # no input at all
    c.on_report(report("/selfish", subs={"/odom": 1, "/sim/imu": 1}))  # one input a member publishes
    assert c.fed_by_the_simulator_alone() == ["/adapters", "/map_server"]


def test_a_member_that_left_is_named_no_more_and_leaving_twice_is_harmless():
    c = Coordinator(["/adapter", "/loc"], "/simulator")
    c.on_report(report("/adapter", subs={"/sim/imu": 1}, pubs={"/imu/data": 1}, next_timer=10))
    c.on_report(report("/loc", subs={"/imu/data": 1}, next_timer=10))
    c.on_report(report("/adapter", seq=1, sent={"/imu/data": 3}, subs={"/sim/imu": 1}, pubs={"/imu/data": 1},
                       next_timer=10))
    assert c.needing(c.watermark({"/sim/imu": 1}, (0, 0))) == ["/adapter", "/loc"]
    c.leave(["/loc"])
    c.leave(["/loc"])
    wm = c.watermark({"/sim/imu": 1}, (0, 0))
    assert c.needing(wm) == ["/adapter"] and c.timers_due(10) == ["/adapter"]
    assert wm["/imu/data"] == {"/adapter": 3}  # what was published still counts
