"""Publishers that write to each subscriber in the publishing thread while it keeps up,
and queue for it only when its socket is full.

A rospy publisher created with a ``queue_size`` gives each subscriber a writer thread of
its own (``QueuedConnection``): every publication appends to that subscriber's queue,
wakes its thread and yields the GIL to it (``write_data`` ends in a zero-second sleep). On
this 2-core VM a wake-up between threads costs more than the send itself: publishing an
Imu at 500 Hz to one subscriber cost the publisher 113-144 us a message queued and
67-73 us written in place (measured side by side, two runs each). ``queue_size=None``
writes in place, but then a subscriber that stops reading (a stopped process,
``rostopic echo`` in a terminal paused with Ctrl-S) blocks the publisher for good once
its socket buffer is full, and with it, in the simulator, the whole simulation.

:class:`InPlaceConnection` does both: a send the socket takes at once (``MSG_DONTWAIT``:
the usual case, a socket buffer holds seconds of any of our streams) is written in the
publishing thread, with no thread woken. A send the socket cannot take whole goes, with
every later message for that subscriber, to a queue that a writer thread of its own
empties with blocking sends, as rospy's queued publisher would, dropping the oldest
messages once ``queue_size`` wait (never the rest of a message already begun on the
wire); once it is empty, sends are in place again. A lagging or stopped subscriber
therefore never blocks the publisher, and it gets every message it can take, in order,
when it reads again.

It reaches into rospy's publisher connections (``_PublisherImpl.add_connection`` and
``connections``); like every such reach, it lives in :mod:`quadrivio_runtime`.
"""

from __future__ import annotations

import socket
import threading
import warnings
from collections import deque
from typing import Deque, Optional

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy
from rospy.exceptions import TransportTerminated


class InPlaceConnection:
    """Wraps one subscriber's rospy transport (``TCPROSTransport``) as rospy's
    ``QueuedConnection`` does, writing in the caller's thread while the socket takes the
    data at once (see the module docstring). ``queue_size``: messages kept while the
    subscriber is behind, 0 for no limit."""

    def __init__(self, connection, queue_size: int) -> None:
        self._connection = connection
        self._queue_size = queue_size
        self._lock = threading.Lock()
        self._cond = threading.Condition(self._lock)
        self._queue: Deque = deque()
        self._partial = False  # the queue's head is the rest of a message begun on the wire
        self._busy = False  # the writer thread is sending an item, outside the lock
        self._error: Optional[BaseException] = None
        self._thread: Optional[threading.Thread] = None
        self.queued = 0  # messages that went through the queue
        self.dropped = 0  # messages dropped from a full queue
        connection.set_cleanup_callback(self._closed)

    # rospy reads the transport's attributes (endpoint_id, stat_bytes, fileno, ...) through
    # the wrapper, and removes a closed transport from the publisher's list by equality
    def __getattr__(self, name):
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self._connection, name)

    def __eq__(self, other) -> bool:
        return other is self or other is self._connection

    def __hash__(self) -> int:
        return id(self._connection)

    def write_data(self, data) -> bool:
        c = self._connection
        with self._lock:
            if self._error is not None:
                error, self._error = self._error, None
                raise error
            sock = c.socket
            if c.done or sock is None:
                raise TransportTerminated("connection closed")
            if self._queue or self._busy:
                self._enqueue(data)
                return True
            try:
                sent = sock.send(data, socket.MSG_DONTWAIT)
            except BlockingIOError:
                sent = 0
            # any other error propagates: the publisher drops this subscriber, as for rospy's own
            c.stat_bytes += sent
            if sent == len(data):
                c.stat_num_msg += 1
                return True
            self._queue.append(memoryview(data)[sent:] if sent else data)
            self._partial = sent > 0
            self.queued += 1
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="inplace_writer", daemon=True)
                self._thread.start()
            self._cond.notify()
        return True

    def _enqueue(self, data) -> None:  # under the lock
        if self._queue_size > 0 and len(self._queue) >= self._queue_size:
            keep = 1 if self._partial else 0
            if len(self._queue) > keep:
                del self._queue[keep]
                self.dropped += 1
        self._queue.append(data)
        self.queued += 1
        self._cond.notify()

    def _closed(self, _connection) -> None:
        with self._lock:
            self._cond.notify()

    def _run(self) -> None:
        c = self._connection
        while True:
            with self._lock:
                while not self._queue and not c.done:
                    self._cond.wait()
                if c.done:
                    self._queue.clear()
                    return
                item = self._queue.popleft()
                self._partial = False
                self._busy = True
                sock = c.socket
            try:
                if sock is None:
                    raise TransportTerminated("connection closed")
                sock.sendall(item)
                c.stat_bytes += len(item)
                c.stat_num_msg += 1
            except Exception as e:  # noqa: BLE001 - raised to the next publish, which drops this subscriber
                with self._lock:
                    self._error = e
                    self._busy = False
                    self._queue.clear()
                return
            with self._lock:
                self._busy = False

    def backlog(self) -> int:
        """Messages waiting for this subscriber (0 while it keeps up)."""
        with self._lock:
            return len(self._queue) + (1 if self._busy else 0)


def in_place(impl, queue_size: int) -> None:
    """Make a rospy publisher implementation (``Publisher.impl``, created with
    ``queue_size=None``) wrap each new subscriber's connection in an
    :class:`InPlaceConnection`, and the ones it already has."""
    if getattr(impl, "_in_place_queue", None) is not None:
        return
    add = impl.add_connection  # rospy's own, bound

    def add_connection(c):
        # A publisher of the topic created later in this process with a queue_size sets
        # the shared implementation's: rospy would then wrap this one in a writer thread too
        queued, impl.queue_size = impl.queue_size, None
        try:
            return add(c if isinstance(c, InPlaceConnection) else InPlaceConnection(c, queue_size))
        finally:
            impl.queue_size = queued

    with impl.c_lock:
        impl.add_connection = add_connection  # rospy's TCPROS handler calls topic.add_connection
        impl._in_place_queue = queue_size
        impl.connections = [c if isinstance(c, InPlaceConnection) else InPlaceConnection(c, queue_size)
                            for c in impl.connections]


def direct_publisher(name: str, data_class, queue_size: int, latch: bool = False) -> rospy.Publisher:
    """``rospy.Publisher(name, data_class, queue_size=queue_size)`` that writes in the
    publishing thread while a subscriber keeps up (see the module docstring).

    rospy shares one publisher implementation per topic and process: when this process
    already has a queued publisher of ``name``, that one's connections stand."""
    if not (isinstance(queue_size, int) and queue_size >= 0):
        raise ValueError(f"queue_size {queue_size!r} must be a whole number >= 0 (0: no limit)")
    with warnings.catch_warnings():  # queue_size=None on purpose: the queue is InPlaceConnection's
        warnings.filterwarnings("ignore", message="The publisher should be created", category=SyntaxWarning)
        pub = rospy.Publisher(name, data_class, queue_size=None, latch=latch)
    if pub.impl.queue_size is not None:
        rospy.logwarn("%s already has a queued publisher in this process: its sends stay queued", pub.resolved_name)
        return pub
    in_place(pub.impl, queue_size)
    return pub
