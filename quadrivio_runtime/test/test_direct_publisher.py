"""direct.InPlaceConnection on rospy's own publisher and transports over loopback TCP (no
master): a subscriber that keeps up is written in place; one that stops reading never
blocks the publisher, and when it reads again it gets whole messages, in order, the
oldest dropped beyond the queue size."""

import socket
import struct
import threading
import time

import pytest
import rospy.topics
from rospy.impl.tcpros_base import TCPROSTransport
from rospy.impl.tcpros_pubsub import TCPROSPub
from std_msgs.msg import String

from quadrivio_runtime.ros.direct import InPlaceConnection, in_place

pytestmark = pytest.mark.wall  # a publisher that must not block, on the wall clock (pytest.ini)

PAD = "x" * 2000


def tcp_pair(small_buffers: bool):
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)
    client = socket.socket()
    if small_buffers:  # full after a few messages
        client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)
    client.connect(server.getsockname())
    sock, _ = server.accept()
    server.close()
    if small_buffers:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4096)
    return sock, client


def transport(sock, name):
    t = TCPROSTransport(TCPROSPub("/t", String), "/t")
    t.set_socket(sock, name)
    return t


class Reader(threading.Thread):
    """Reads TCPROS frames of String messages "<index>:<padding>" and keeps the indices."""

    def __init__(self, sock, start=True):
        super().__init__(daemon=True)
        self.sock, self.got, self.buf, self.broken = sock, [], b"", False
        self.go = threading.Event()
        if start:
            self.go.set()
        self.start()

    def run(self):
        self.go.wait()
        while True:
            try:
                data = self.sock.recv(1 << 20)
            except OSError:  # closed by the test
                return
            if not data:
                return
            self.buf += data
            i = 0
            while len(self.buf) - i >= 4:
                (n,) = struct.unpack_from("<I", self.buf, i)
                if len(self.buf) - i < 4 + n:
                    break
                (m,) = struct.unpack_from("<I", self.buf, i + 4)
                if m != n - 4:
                    self.broken = True  # a frame that is not one whole String
                self.got.append(int(self.buf[i + 8:i + 4 + n].split(b":")[0]))
                i += 4 + n
            self.buf = self.buf[i:]


def wait(cond, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


@pytest.fixture
def publisher():
    impl = rospy.topics._PublisherImpl("/t", String)
    impl.set_queue_size(None)
    yield impl
    impl.close()


def publish(impl, n, budget, first=0):
    t0 = time.monotonic()
    for i in range(first, first + n):
        impl.publish(String(data=f"{i}:{PAD}"))
        assert time.monotonic() - t0 < budget, "the publisher is blocked"
    return time.monotonic() - t0


def test_a_stopped_subscriber_blocks_nothing_and_gets_whole_messages_when_it_reads_again(publisher):
    in_place(publisher, queue_size=50)
    good, good_peer = tcp_pair(small_buffers=False)
    slow, slow_peer = tcp_pair(small_buffers=True)
    reader = Reader(good_peer)
    stopped = Reader(slow_peer, start=False)  # reads nothing until told
    publisher.add_connection(transport(good, "good"))
    publisher.add_connection(transport(slow, "slow"))
    conns = {c.endpoint_id: c for c in publisher.connections}
    assert all(isinstance(c, InPlaceConnection) for c in conns.values())

    elapsed = publish(publisher, 300, budget=10.0)
    assert elapsed < 3.0, f"300 publications took {elapsed:.2f} s"
    wait(lambda: len(reader.got) == 300)
    assert reader.got == list(range(300)) and not reader.broken
    assert conns["good"].queued == 0  # all of it written in place

    slow_c = conns["slow"]
    assert slow_c.queued > 200 and slow_c.dropped > 150
    stopped.go.set()
    wait(lambda: slow_c.backlog() == 0 and stopped.got and stopped.got[-1] == 299)
    got = stopped.got
    assert not stopped.broken
    assert got == sorted(got) and len(set(got)) == len(got)  # in order, none twice
    assert len(got) == 300 - slow_c.dropped
    assert got[:3] == [0, 1, 2]  # what the socket took before it was full
    assert got[-50:] == list(range(250, 300))  # the newest queue_size, none dropped there

    # back in place once the backlog is gone
    before = slow_c.queued
    for i in range(300, 305):  # each read before the next: the socket takes each whole
        publish(publisher, 1, budget=5.0, first=i)
        wait(lambda: stopped.got[-1] == i)
    assert slow_c.queued == before
    for s in (good_peer, slow_peer):
        s.close()


def test_without_it_a_stopped_subscriber_blocks_the_publisher(publisher):
    """The failure InPlaceConnection prevents (and what makes the test above able to fail)."""
    slow, slow_peer = tcp_pair(small_buffers=True)
    publisher.add_connection(transport(slow, "slow"))
    done = threading.Event()
    threading.Thread(target=lambda: (publish(publisher, 200, budget=60.0), done.set()), daemon=True).start()
    assert not done.wait(1.0), "publishing to a subscriber that never reads did not block"
    slow_peer.close()  # the blocked send fails: the thread ends
    assert done.wait(5.0)


def test_a_subscriber_that_goes_away_is_dropped(publisher):
    in_place(publisher, queue_size=10)
    a, pa = tcp_pair(small_buffers=True)
    b, pb = tcp_pair(small_buffers=False)
    reader = Reader(pb)
    publisher.add_connection(transport(a, "gone"))
    publisher.add_connection(transport(b, "stays"))
    publish(publisher, 20, budget=5.0)  # "gone" falls behind: its writer thread blocks
    pa.close()  # its blocked send fails; the next publication drops it
    n = 20
    while [c.endpoint_id for c in publisher.connections] != ["stays"]:
        assert n < 1000, "the closed subscriber was never dropped"
        publish(publisher, 1, budget=5.0, first=n)
        n += 1
    publish(publisher, 3, budget=5.0, first=n)
    wait(lambda: len(reader.got) == n + 3)
    assert reader.got == list(range(n + 3))  # the other subscriber lost nothing
    pb.close()


def test_in_place_wraps_the_connections_it_already_has(publisher):
    a, pa = tcp_pair(small_buffers=False)
    publisher.add_connection(transport(a, "early"))
    in_place(publisher, queue_size=5)
    in_place(publisher, queue_size=5)  # once
    (c,) = publisher.connections
    assert isinstance(c, InPlaceConnection) and not isinstance(c._connection, InPlaceConnection)
    assert c == c._connection and c.endpoint_id == "early"
    a.close()
    pa.close()


def test_a_queued_publisher_of_the_same_topic_made_later_adds_no_writer_thread(publisher):
    """rospy shares one implementation per topic: a later Publisher(queue_size=N) sets its
    queue size, which must not wrap new subscribers in rospy's QueuedConnection."""
    in_place(publisher, queue_size=5)
    publisher.set_queue_size(100)
    a, pa = tcp_pair(small_buffers=False)
    publisher.add_connection(transport(a, "late"))
    (c,) = publisher.connections
    assert type(c) is InPlaceConnection and publisher.queue_size == 100
    a.close()
    pa.close()
