"""lockstep's patch of rospy (quadrivio_runtime.ros.lockstep._patch) on rospy's own publisher and
subscriber implementations and TCPROS transports over loopback sockets (no master):

* a member holds back what arrives on the loop's topics: rospy's receive loop hands the
  messages to the member instead of the callbacks, in order, and the round delivers them
  later, whole, to every callback;
* topics outside the loop (/clock, /rosout, /diagnostics, /tf) go straight to the callbacks;
* every publication on a loop topic is counted once, and really leaves on the wire; one
  outside the loop, or a latched re-send to one connection, is not counted.
"""

import io
import socket
import struct
import threading
import time

import pytest
from rospy.impl.tcpros_base import TCPROSTransport
from rospy.impl.tcpros_pubsub import TCPROSSub
from rospy.topics import _PublisherImpl, _SubscriberImpl
from std_msgs.msg import String

from quadrivio_runtime.ros import lockstep

pytestmark = pytest.mark.wall  # socket threads waited for against the wall clock (pytest.ini)


def frame(text):
    b = io.BytesIO()
    String(data=text).serialize(b)
    return struct.pack("<I", len(b.getvalue())) + b.getvalue()


def wait(cond, timeout=10.0):
    deadline = time.monotonic() + timeout
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.002)


class HeldBack:
    """What a lockstep member does with received messages (Member.received): queue them."""

    def __init__(self):
        self.lock = threading.Lock()
        self.queue = []

    def received(self, impl, msgs, connection):
        with self.lock:
            self.queue.extend((impl, m) for m in msgs)

    def taken(self):
        with self.lock:
            out, self.queue = self.queue, []
        return out


@pytest.fixture
def patched():
    """lockstep's patch with a counter and a member; rospy's classes restored afterwards."""
    saved = (_PublisherImpl.publish, _SubscriberImpl.receive_callback)
    counted, member = [], HeldBack()
    lockstep._patch(counted.append, member)
    yield counted, member
    _PublisherImpl.publish, _SubscriberImpl.receive_callback = saved
    del _PublisherImpl._lockstep_patched


def subscription(topic):
    """A rospy subscriber implementation fed by a real TCPROS transport over a socket pair, its
    receive loop in a thread as rospy runs it; returns (impl, what its callback got, peer)."""
    impl = _SubscriberImpl(topic, String)
    got = []
    impl.add_callback(lambda m: got.append((m.data, threading.current_thread().name)), None)
    a, peer = socket.socketpair()
    t = TCPROSTransport(TCPROSSub(topic, String), topic)
    t.set_socket(a, topic)
    th = threading.Thread(target=t.receive_loop, args=(impl.receive_callback,), name=f"recv{topic}", daemon=True)
    th.start()
    t.thread = th
    return impl, got, peer, t


def close(t, peer):
    """Hang up and wait for the receive loop to end: a loop left reading could take a later
    test's socket that reuses the number."""
    peer.close()
    t.close()
    if getattr(t, "thread", None) is not None:
        t.thread.join(5.0)
        assert not t.thread.is_alive()


def test_a_member_holds_back_loop_topics_and_the_round_delivers_them_in_order(patched):
    _counted, member = patched
    impl, got, peer, t = subscription("/vehicle/state")
    try:
        wire = b"".join(frame(f"m{k}") for k in range(50))
        for k in range(0, len(wire), 7):  # split anywhere
            peer.sendall(wire[k:k + 7])
        wait(lambda: len(member.queue) == 50)
        time.sleep(0.05)
        assert got == []  # held back: nothing reached the callback from rospy's thread
        batch = member.taken()
        assert [m.data for _, m in batch] == [f"m{k}" for k in range(50)] and all(i is impl for i, _ in batch)
        for i, m in batch:  # the round's delivery, in the round's thread
            lockstep._deliver(i, m)
        assert [d for d, _ in got] == [f"m{k}" for k in range(50)]
        assert {th for _, th in got} == {threading.current_thread().name}
    finally:
        close(t, peer)


@pytest.mark.parametrize("topic", ["/clock", "/rosout", "/diagnostics", "/tf"])
def test_topics_outside_the_loop_are_not_held_back(patched, topic):
    _counted, member = patched
    impl, got, peer, t = subscription(topic)
    try:
        peer.sendall(frame("a") + frame("b"))
        wait(lambda: len(got) == 2)
        assert [d for d, _ in got] == ["a", "b"] and member.queue == []
        assert {th for _, th in got} == {f"recv{topic}"}  # rospy's own thread, at once
    finally:
        close(t, peer)


def publisher(topic):
    impl = _PublisherImpl(topic, String)
    a, peer = socket.socketpair()
    t = TCPROSTransport(TCPROSSub(topic, String), topic)  # a connection the publisher writes to
    t.set_socket(a, topic)
    impl.add_connection(t)
    return impl, peer, t


def read_frames(peer, n, timeout=5.0):
    peer.settimeout(timeout)
    buf, out = b"", []
    while len(out) < n:
        buf += peer.recv(65536)
        while len(buf) >= 4 and len(buf) >= 4 + struct.unpack("<I", buf[:4])[0]:
            size = struct.unpack("<I", buf[:4])[0]
            m = String()
            m.deserialize(buf[4:4 + size])
            out.append(m.data)
            buf = buf[4 + size:]
    return out


def test_publications_on_loop_topics_are_counted_once_and_leave_on_the_wire(patched):
    counted, _member = patched
    loop, loop_peer, t1 = publisher("/localization/odom")
    diag, diag_peer, t2 = publisher("/diagnostics")
    try:
        for k in range(5):
            assert loop.publish(String(data=f"x{k}")) is not False
        diag.publish(String(data="d"))
        loop.publish(String(data="latched re-send"), connection_override=t1)  # a new subscriber's latch
        assert counted == ["/localization/odom"] * 5
        assert read_frames(loop_peer, 6) == [f"x{k}" for k in range(5)] + ["latched re-send"]
        assert read_frames(diag_peer, 1) == ["d"]
    finally:
        close(t1, loop_peer)
        close(t2, diag_peer)


def test_the_patch_is_applied_once(patched):
    counted, _ = patched
    lockstep._patch(counted.append, None)  # a second install must not count twice
    pub, peer, t = publisher("/planner/path")
    try:
        pub.publish(String(data="p"))
        assert counted == ["/planner/path"]
    finally:
        close(t, peer)
