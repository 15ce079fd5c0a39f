"""One thread receives every subscription of a process, instead of rospy's thread per
connection.

rospy gives each subscribed connection a thread that blocks in ``recv`` (``TCPROSTransport.
receive_loop``). When the simulator's step reaches a process, the /clock tick and each
sensor reading arrive together, and that many threads wake at once and take turns at the
GIL: the sensor adapters' process made about 2000 futex calls a second for 275 messages
(``strace -c``), 7 per message, and each handoff of the GIL between two threads is a
context switch. Here one thread waits on all the process's subscription sockets
(``selectors``), reads what each has, and runs the callbacks of the messages it completed,
in the order the sockets became readable: a burst costs one wake-up.

What stays rospy's: connecting (``robust_connect_subscriber``'s retries run in rospy's
connecting thread as before, which then hands the connection over instead of reading it),
the wire format (``protocol.read_messages``: partial messages wait in the connection's
buffer, ``queue_size`` drops the oldest of one read as rospy does), the callbacks
(``_SubscriberImpl.receive_callback``, so lockstep's wrapper and rospy's exception
logging apply), statistics, latching, and every error path: a connection that fails is
handed back to a thread of its own running rospy's ``receive_loop``, which closes it
after a hang-up and reconnects it after any other error (a message that does not
deserialise among them, as in rospy's ``receive_once``).

The cost: callbacks of different topics no longer run in parallel threads. They did not
in Python code anyway (the GIL); a callback that blocks (a long computation that
releases the GIL, a sleep, a wait for a clock tick) now delays the others of its
process, and one waiting for a message of the same process would wait for good. So
:func:`install` is for nodes whose callbacks are short and never wait.

Why only some nodes use it: the sensor adapters, whose inputs all come from the
simulator's step in one burst, spend about a fifth less CPU with it (``bench_sensors``);
nodes whose inputs come from different processes at different moments (the follower,
the roll-over monitor, localization) did not gain, and keep rospy's threads. The
measurements: ``bench/HISTORY.md`` ("One receiving thread").

``QUADRIVIO_RECEIVER=0`` in a node's environment keeps rospy's thread per connection
(A/B measurements, or to rule this module out).
"""

from __future__ import annotations

import errno
import logging
import os
import selectors
import socket
import threading
import traceback
from typing import Callable, Dict, List, Optional, Tuple

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy
import rospy.impl.tcpros_pubsub as pubsub
from genpy import DeserializationError
from rospy.exceptions import TransportTerminated

_log = logging.getLogger("rospy.quadrivio.receiver")


class Receiver:
    """The receiving thread of a process (see the module docstring). ``add(conn, cb)``
    from any thread: read ``conn`` (a connected ``TCPROSTransport``) from now on and call
    ``cb(msgs, conn)`` with what it completes."""

    def __init__(self, is_shutdown: Callable[[], bool]) -> None:
        self._is_shutdown = is_shutdown
        self._sel = selectors.DefaultSelector()
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self._sel.register(self._wake_r, selectors.EVENT_READ, None)
        self._lock = threading.Lock()
        self._pending: List[Tuple[object, Callable]] = []
        self._conns: Dict[int, Tuple[object, Callable]] = {}  # fd -> (conn, callback)
        self._taking = True  # False after release(): connections go to rospy's threads
        self.handed_back = 0  # connections given back to rospy's receive_loop
        self._thread = threading.Thread(target=self._run, name="receiver", daemon=True)
        self._thread.start()

    def add(self, conn, cb: Callable) -> bool:
        """Read ``conn`` from now on; False after :meth:`release` (the caller reads it)."""
        with self._lock:
            if not self._taking:
                return False
            self._pending.append((conn, cb))
        self._wake()
        return True

    def release(self) -> None:
        """Give every connection back to a rospy thread of its own, and let rospy keep the
        ones that come later: for a node whose callbacks wait for other messages (a
        lockstep member's round waits, inside the command's callback, for the clock and
        the round's messages)."""
        with self._lock:
            self._taking = False
        self._wake()

    def _wake(self) -> None:
        try:
            self._wake_w.send(b"\0")
        except BlockingIOError:  # a wake-up is already waiting
            pass

    def connections(self) -> int:
        with self._lock:
            return len(self._conns) + len(self._pending)

    # ------------------------------------------------------------------ thread
    def _run(self) -> None:
        while not self._is_shutdown():
            try:
                events = self._sel.select(timeout=0.5)
            except OSError as exc:  # EBADF: a socket closed under the selector; swept below
                _log.debug("receiver select: %s", exc)
                events = []
            for key, _mask in events:
                # Nothing one connection does may end the thread that reads all of them
                try:
                    if key.data is None:
                        self._take_pending()
                        continue
                    conn, cb = key.data
                    self._read(key.fd, conn, cb)
                except Exception:  # noqa: BLE001
                    _log.error("receiver: %s", traceback.format_exc())
            self._sweep()
        for fd in list(self._conns):
            self._drop(fd)

    def _take_pending(self) -> None:
        try:
            while self._wake_r.recv(4096):
                pass
        except BlockingIOError:
            pass
        with self._lock:
            pending, self._pending = self._pending, []
            taking = self._taking
        if not taking:
            for fd, (conn, cb) in list(self._conns.items()):
                self._drop(fd)
                pending.append((conn, cb))
            for conn, cb in pending:
                self._to_rospy(conn, cb)
            return
        for conn, cb in pending:
            sock = conn.socket
            if conn.done or sock is None:
                continue
            try:
                fd = sock.fileno()
                sock.setblocking(False)
            except OSError:
                continue
            if fd in self._conns:  # a closed socket's number, reused: the kernel dropped it from epoll
                self._drop(fd)
            self._conns[fd] = (conn, cb)
            self._sel.register(fd, selectors.EVENT_READ, (conn, cb))

    def _drop(self, fd: int) -> None:
        self._conns.pop(fd, None)
        try:
            self._sel.unregister(fd)
        except (KeyError, ValueError, OSError):
            pass

    def _sweep(self) -> None:
        for fd, (conn, _cb) in list(self._conns.items()):
            sock = conn.socket
            if conn.done or sock is None or sock.fileno() != fd:
                self._drop(fd)

    def _read(self, fd: int, conn, cb: Callable) -> None:
        sock, b, p = conn.socket, conn.read_buff, conn.protocol
        if conn.done or sock is None:
            self._drop(fd)
            return
        msgs: List = []
        try:
            while True:
                try:
                    d = sock.recv(p.buff_size)
                except (BlockingIOError, InterruptedError):
                    break
                if not d:
                    raise TransportTerminated("unable to receive data from sender, check sender's logs for details")
                b.write(d)
                conn.stat_bytes += len(d)
                if len(d) < p.buff_size:
                    break
            if b.tell() >= 4:
                p.read_messages(b, msgs, sock)
        except Exception as exc:  # noqa: BLE001 - rospy's receive_loop decides: close or reconnect
            if isinstance(exc, DeserializationError):  # rospy's receive_once: a transport error, so reconnect
                _log.error("[%s] cannot deserialise a message: %s; reconnecting", conn.name, exc)
            self._hand_back(fd, conn, cb, exc)
            return
        if not msgs:
            return
        conn.stat_num_msg += len(msgs)
        for m in msgs:
            m._connection_header = conn.header
        if conn.is_latched:
            conn.latch = msgs[-1]
        if not conn.done and not self._is_shutdown():
            try:
                cb(msgs, conn)
            except Exception:  # noqa: BLE001 - as rospy's receive_loop: logged, the connection read on
                _log.error("[%s] callback failed: %s", conn.name, traceback.format_exc())

    def _to_rospy(self, conn, cb: Callable) -> None:
        """A healthy connection back to rospy's receive_loop (what was read of a message
        waits in its buffer, which receive_once reads first)."""
        self.handed_back += 1
        try:
            if conn.socket is not None:
                conn.socket.setblocking(True)
        except OSError:
            pass
        threading.Thread(target=conn.receive_loop, args=(cb,), name=conn.name, daemon=True).start()

    def _hand_back(self, fd: int, conn, cb: Callable, exc: BaseException) -> None:
        self._drop(fd)
        self.handed_back += 1
        hung_up = isinstance(exc, TransportTerminated) or (isinstance(exc, OSError) and exc.errno in (
            errno.ECONNRESET, errno.EPIPE))
        _log.debug("[%s] receive: %s; back to rospy's receive_loop", conn.name, exc)

        def run() -> None:
            if hung_up:
                if not conn.done:
                    conn.close()
                return
            try:  # rospy's TransportException path: drop the socket, then reconnect
                if conn.socket is not None:
                    conn.socket.close()
            except OSError:
                pass
            conn.socket = None
            conn.receive_loop(cb)
        threading.Thread(target=run, name=f"{conn.name} (reconnect)", daemon=True).start()


_receiver: Optional[Receiver] = None


def install() -> Receiver:
    """Make the subscriptions this process connects from now on be read by one
    :class:`Receiver` thread (see the module docstring); call it before ``init_node`` so
    that /clock's is among them. Idempotent."""
    global _receiver
    if _receiver is not None:
        return _receiver
    original = pubsub.robust_connect_subscriber
    _receiver = receiver = Receiver(rospy.is_shutdown)

    def robust_connect_subscriber(conn, dest_addr, dest_port, pub_uri, receive_cb, resolved_topic_name):
        # rospy's connecting and retries, in rospy's thread; then the receiver reads it
        # (after release(), this thread does, as in rospy)
        loop = conn.receive_loop
        conn.receive_loop = lambda cb: receiver.add(conn, cb) or loop(cb)
        try:
            original(conn, dest_addr, dest_port, pub_uri, receive_cb, resolved_topic_name)
        finally:
            conn.receive_loop = loop

    robust_connect_subscriber.quadrivio_receiver = True
    pubsub.robust_connect_subscriber = robust_connect_subscriber
    return receiver


def release() -> None:
    """:meth:`Receiver.release` of this process's receiver, if it has one."""
    if _receiver is not None:
        _receiver.release()


def wanted() -> bool:
    """Whether this process should :func:`install` it: unless ``QUADRIVIO_RECEIVER=0``."""
    return os.environ.get("QUADRIVIO_RECEIVER", "1").strip() != "0"
