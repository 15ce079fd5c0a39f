"""receiver.Receiver on rospy's own subscriber transports over loopback TCP (no master):
one thread reads every connection, messages split anywhere on the wire arrive whole and
in order, a hang-up closes the connection as rospy's receive_loop would, another
transport error or a message that does not deserialise hands it back to rospy's
receive_loop (which reconnects), the oldest of one read are dropped beyond the queue
size, and a socket number reused after a close is read again."""

import io
import socket
import struct
import threading
import time

import pytest
from rospy.impl.tcpros_base import TCPROSTransport
from rospy.impl.tcpros_pubsub import TCPROSSub
from std_msgs.msg import Header, String

from quadrivio_runtime.ros.receiver import Receiver

pytestmark = pytest.mark.wall  # socket threads waited for against the wall clock (pytest.ini)


def frame(text: str) -> bytes:
    b = io.BytesIO()
    String(data=text).serialize(b)
    body = b.getvalue()
    return struct.pack("<I", len(body)) + body


def subscriber(name="/t", queue_size=None):
    a, b = socket.socketpair()
    t = TCPROSTransport(TCPROSSub(name, String, queue_size=queue_size), name)
    t.set_socket(a, name)
    return t, b


def wait(cond, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.002)


class Sink:
    def __init__(self):
        self.got, self.threads, self.lock = [], set(), threading.Lock()

    def __call__(self, msgs, conn):
        with self.lock:
            self.got.extend((conn.name, m.data) for m in msgs)
            self.threads.add(threading.current_thread().name)

    def of(self, name):
        with self.lock:
            return [d for n, d in self.got if n == name]


@pytest.fixture
def receiver():
    stop = threading.Event()
    r = Receiver(stop.is_set)
    yield r
    stop.set()


def test_messages_split_anywhere_arrive_whole_in_order_from_every_connection_in_one_thread(receiver):
    sink = Sink()
    conns = [subscriber(f"/t{i}") for i in range(4)]
    for c, _ in conns:
        receiver.add(c, sink)
    wire = {c.name: b"".join(frame(f"{c.name}:{k}:" + "x" * (k * 37 % 300)) for k in range(200)) for c, _ in conns}
    # cut each stream into pieces of 1 to 97 bytes, interleaved across the connections
    pos = {n: 0 for n in wire}
    k = 0
    while any(pos[n] < len(wire[n]) for n in wire):
        for c, peer in conns:
            n = c.name
            step = 1 + (k * 31) % 97
            peer.sendall(wire[n][pos[n]:pos[n] + step])
            pos[n] += step
            k += 1
    wait(lambda: all(len(sink.of(c.name)) == 200 for c, _ in conns))
    for c, _ in conns:
        assert [int(d.split(":")[1]) for d in sink.of(c.name)] == list(range(200))
        assert c.stat_num_msg == 200 and c.stat_bytes == len(wire[c.name])
    assert sink.threads == {"receiver"}
    assert receiver.handed_back == 0


def test_a_hang_up_closes_the_connection_as_rospy_does(receiver):
    sink = Sink()
    c, peer = subscriber()
    closed = threading.Event()
    c.set_cleanup_callback(lambda _c: closed.set())
    receiver.add(c, sink)
    peer.sendall(frame("last"))
    peer.close()
    wait(closed.is_set)
    assert sink.of("/t") == ["last"] and c.done
    wait(lambda: receiver.connections() == 0)


def test_another_transport_error_goes_back_to_rospys_receive_loop(receiver, monkeypatch):
    c, peer = subscriber()
    handed = threading.Event()
    monkeypatch.setattr(c, "receive_loop", lambda cb: handed.set())  # rospy would reconnect here

    def broken(*_a):
        raise OSError(5, "I/O error")
    c.protocol.read_messages = broken
    receiver.add(c, Sink())
    peer.sendall(frame("x"))
    wait(handed.is_set)
    assert receiver.handed_back == 1 and c.socket is None and not c.done
    wait(lambda: receiver.connections() == 0)


def test_a_message_that_does_not_deserialise_reconnects_as_in_rospy(receiver, monkeypatch):
    sink = Sink()
    c, peer = subscriber(name="/h")
    c.protocol = TCPROSSub("/h", Header)
    handed = threading.Event()
    monkeypatch.setattr(c, "receive_loop", lambda cb: handed.set())
    receiver.add(c, sink)
    peer.sendall(struct.pack("<I", 3) + b"abc")  # a Header in 3 bytes
    wait(handed.is_set)
    assert receiver.handed_back == 1 and c.socket is None and not sink.of("/h")


def test_a_socket_number_reused_after_a_close_is_read_again(receiver):
    sink = Sink()
    c1, p1 = subscriber("/a")
    receiver.add(c1, sink)
    p1.sendall(frame("a1"))
    wait(lambda: sink.of("/a") == ["a1"])
    fd = c1.socket.fileno()
    c1.close()  # rospy unsubscribing: done, socket closed, its number free
    for _ in range(20):  # the kernel hands out the lowest free number: it comes back
        c2, p2 = subscriber("/b")
        if c2.socket.fileno() == fd:
            break
    assert c2.socket.fileno() == fd
    receiver.add(c2, sink)
    p2.sendall(frame("b1"))
    wait(lambda: sink.of("/b") == ["b1"])


def test_the_oldest_of_one_read_are_dropped_beyond_the_queue_size_as_rospy_does(receiver):
    sink = Sink()
    c, peer = subscriber(queue_size=2)
    peer.sendall(b"".join(frame(str(i)) for i in range(10)))  # all in the socket before the first read
    receiver.add(c, sink)
    wait(lambda: sink.of("/t"))
    time.sleep(0.05)
    assert sink.of("/t") == ["8", "9"]


def test_release_gives_every_connection_back_to_a_rospy_thread_with_what_was_half_read(receiver):
    sink = Sink()
    c, peer = subscriber()
    receiver.add(c, sink)
    whole = frame("one") + frame("two")
    peer.sendall(frame("zero") + whole[:5])  # "one" cut after its first byte
    wait(lambda: sink.of("/t") == ["zero"])
    time.sleep(0.05)  # the cut bytes read into the connection's buffer
    receiver.release()
    wait(lambda: receiver.connections() == 0)
    assert receiver.add(subscriber("/later")[0], sink) is False  # later ones: rospy's
    peer.sendall(whole[5:])
    wait(lambda: sink.of("/t") == ["zero", "one", "two"])
    assert "/t" in sink.threads  # rospy's receive_loop, in a thread named after the topic


def test_install_hands_rospys_connections_to_one_receiver_and_release_without_one_is_harmless(monkeypatch):
    import rospy.impl.tcpros_pubsub as pubsub
    from quadrivio_runtime.ros import receiver as R

    monkeypatch.setattr(R, "_receiver", None)
    calls = []

    def original(conn, *_a):  # rospy's: connect, then read in this thread
        conn.receive_loop("cb")
    monkeypatch.setattr(pubsub, "robust_connect_subscriber", original)
    R.release()  # no receiver yet: nothing to do
    r = R.install()
    assert R.install() is r and pubsub.robust_connect_subscriber is not original

    class Conn:
        name, socket, done = "/c", None, True

        def receive_loop(self, cb):
            calls.append(cb)
    c = Conn()
    pubsub.robust_connect_subscriber(c, "h", 1, "uri", "cb", "/c")
    assert calls == []
    # taken by the receiver's thread, which skips it (it is done); released before that, it
    # would go back to rospy's loop and be counted below
    wait(lambda: r.connections() == 0)
    R.release()
    pubsub.robust_connect_subscriber(c, "h", 1, "uri", "cb", "/c")
    assert calls == ["cb"]  # after release, rospy's loop in rospy's thread
    assert c.receive_loop.__func__ is Conn.receive_loop  # restored
    monkeypatch.setattr(R, "_receiver", None)


def test_a_callback_that_raises_ends_neither_its_connection_nor_the_others(receiver):
    sink = Sink()
    bad, bad_peer = subscriber("/bad")
    good, good_peer = subscriber("/good")

    def explode(msgs, conn):
        raise RuntimeError("a callback's bug")
    receiver.add(bad, explode)
    receiver.add(good, sink)
    bad_peer.sendall(frame("x"))
    good_peer.sendall(frame("1"))
    wait(lambda: sink.of("/good") == ["1"])
    bad_peer.sendall(frame("y"))
    good_peer.sendall(frame("2"))
    wait(lambda: sink.of("/good") == ["1", "2"])
    assert bad.stat_num_msg == 2 and not bad.done and receiver.handed_back == 0
