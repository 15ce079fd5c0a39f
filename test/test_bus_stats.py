"""bus_stats on answers as roscpp and rospy give them (captured from Debian's roscore,
``rostopic pub`` (rospy) publishing to ``rosbag record`` (roscpp))."""
import pytest

from quadrivio.bus_stats import BusStatsError, behind, inbound_ports, received, sent, socket_quiet, tcp_queues

REC = "/record_1795664964567490033"
PUB_URI = "http://vm:41611/"
# the recorder (roscpp): bus info wrapped, bus stats bare
REC_INFO = [1, "", [[0, "/rosout", "o", "TCPROS", "/rosout", True, "..."],
                    [1, PUB_URI, "i", "TCPROS", "/chatter", True, "..."]]]
REC_STATS = [[["/rosout", [[0, 0, 0, 0, 0]]]], [["/chatter", [[1, 420, 70, 0, 0]]]]]
# the publisher (rospy): both wrapped
PY_INFO = [1, "bus info", [[1, REC, "o", "TCPROS", "/chatter", True, "..."]]]
PY_STATS = [1, "", [[["/chatter", 700, [[1, 880, 70, True]]]], [], []]]
# a roscpp publisher of /tf to the recorder and to someone else
CPP_INFO = [1, "", [[4, "/other", "o", "TCPROS", "/tf", True, "..."], [7, REC, "o", "TCPROS", "/tf", True, "..."]]]
CPP_STATS = [[["/tf", [[4, 9000, 8000, 99, 0], [7, 900, 800, 12, 0]]]], []]


def test_counts_from_either_library():
    assert received(REC_INFO, REC_STATS, {"/chatter"}) == {("/chatter", PUB_URI): 70}
    assert sent(PY_INFO, PY_STATS, REC, {"/chatter"}) == {"/chatter": 70}
    assert sent(CPP_INFO, CPP_STATS, REC, {"/tf"}) == {"/tf": 12}  # only the recorder's connection
    assert sent(CPP_INFO, CPP_STATS, REC, {"/chatter"}) == {}


def test_behind_names_what_is_in_flight():
    got = received(REC_INFO, REC_STATS, {"/chatter"})
    assert behind({("/chatter", PUB_URI): 70}, got, {}, {}) == []
    assert behind({("/chatter", PUB_URI): 71}, got, {}, {}) == [("/chatter", PUB_URI, 71, 70)]
    # a publisher the recorder has not listed yet has delivered nothing
    assert behind({("/tf", "http://b:1/"): 3}, got, {}, {}) == [("/tf", "http://b:1/", 3, 0)]
    assert behind({("/tf", "http://b:1/"): 0}, got, {}, {}) == []


# roscpp's subscription stats as the recorder gave them with three /tf publishers: one
# row only, that of the last link (Subscription::getStats never advances its index)
TF_INFO = [1, "", [[26, "http://vm:45519/", "i", "TCPROS", "/tf", True,
                    "TCPROS connection on port 42366 to [vm:34065 on socket 11]"],
                   [27, "http://vm:40891/", "i", "TCPROS", "/tf", True,
                    "TCPROS connection on port 42370 to [127.0.0.1:34111 on socket 12]"],
                   [28, "http://vm:35129/", "i", "TCPROS", "/tf", True, "TCPROS connection on port 42371 to [vm:1 on"]]]
TF_STATS = [[], [["/tf", [[28, 126141, 1381, 0, 0]]]]]
TCP = """  sl  local_address rem_address   st tx_queue rx_queue tr tm->when retrnsmt   uid  timeout inode
   0: 0100007F:A57E 0100007F:8511 01 00000000:00000000 00:00000000 00000000     0        0 1 1 0
   1: 0100007F:8511 0100007F:A57E 01 00000000:00000000 00:00000000 00000000     0        0 2 1 0
   2: 0100007F:A582 0100007F:853F 01 00000000:0000002C 00:00000000 00000000     0        0 3 1 0
   3: 0100007F:853F 0100007F:A582 01 00000000:00000000 00:00000000 00000000     0        0 4 1 0
"""


def test_connections_the_recorder_does_not_count_fall_back_on_the_kernel():
    got = received(TF_INFO, TF_STATS, {"/tf"})
    assert got == {("/tf", "http://vm:45519/"): None, ("/tf", "http://vm:40891/"): None, ("/tf", "http://vm:35129/"): 1381}
    ports = inbound_ports(TF_INFO, {"/tf"})
    assert ports[("/tf", "http://vm:45519/")] == (42366, 34065)
    assert ports[("/tf", "http://vm:40891/")] == (42370, 34111)
    queues = tcp_queues(TCP, "  sl  local_address remote_address st tx_queue rx_queue\n")
    assert queues[(42370, 34111)] == (0, 44)
    quiet = {k: socket_quiet(p, queues) for k, p in ports.items()}
    assert quiet == {("/tf", "http://vm:45519/"): True, ("/tf", "http://vm:40891/"): False,  # 44 bytes unread
                     ("/tf", "http://vm:35129/"): False}  # its ports are not on the tables
    a, b, c = ("/tf", "http://vm:45519/"), ("/tf", "http://vm:40891/"), ("/tf", "http://vm:35129/")
    now = {a: 400, b: 1000, c: 1381}
    # b has bytes waiting; a is quiet but its count moved since the last look
    assert behind(now, got, {a: 399, b: 1000, c: 1381}, quiet) == [(*b, 1000, None), (*a, 400, None)]
    quiet[b] = True
    assert behind(now, got, {a: 400, b: 1000}, quiet) == []


@pytest.mark.parametrize("answer", [None, 3, [0, "no such node", []], [1, "", [["short"]]]])
def test_answers_in_no_known_shape_are_named(answer):
    with pytest.raises(BusStatsError):
        received(answer, REC_STATS, {"/chatter"})


def test_malformed_stats_are_named():
    with pytest.raises(BusStatsError, match="subscription"):
        received(REC_INFO, [[], [["/chatter", [["x"]]]]], {"/chatter"})
    with pytest.raises(BusStatsError, match="publication"):
        sent(CPP_INFO, [[["/tf", [[7]]]]], REC, {"/tf"})
