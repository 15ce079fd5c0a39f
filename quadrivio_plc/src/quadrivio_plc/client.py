"""PLCClient core: the manual/autonomous multiplexer and the TCP link to the PLC.

Both are ROS-free. :class:`Multiplexer` decides, for the PLC's mode, which setpoint
frames to send (paper section 2.2: the PLC node "acts as a multiplexer between the
autonomous drive and the manual setpoints, depending on the current operating mode").
:class:`PlcLink` owns the socket: it connects, answers the PLC's HELLO challenge with
the shared key (``PROTOCOL.md``, "Sessions"), and only then sends anything else; it
retries with an exponential backoff that is reset only once a session is established
(a PLC that refuses us is not hammered). It decodes the PLC's frames with the shared
codec, measures round-trip times from each frame to its ACK, and counts bad and lost
frames. Sending is thread-safe; receiving happens in :meth:`PlcLink.poll`, called from
one I/O thread.
"""

from __future__ import annotations

import math
import selectors
import socket
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Callable, Deque, Dict, List, Optional, Tuple

from quadrivio_config import param

from . import protocol


@dataclass(frozen=True)
class PlcClientParams:
    host: str = param("127.0.0.1", doc="PLC address: loopback for the emulated PLC, the vehicle's PLC on the real one")
    port: int = param(protocol.DEFAULT_PORT, lo=1, hi=65535, doc="PLC TCP port")
    send_rate: float = param(50.0, lo=1.0, hi=1000.0, unit="Hz", doc="setpoint / heartbeat rate (ROS time)")
    setpoint_timeout: float = param(0.25, lo=0.01, hi=10.0, unit="s",
                                    doc="a setpoint older than this is replaced by a stop")
    stop_brake: float = param(0.5, lo=0.0, hi=1.0, doc="brake of the stop sent for stale setpoints")
    connect_timeout: float = param(1.0, lo=0.05, hi=30.0, unit="s", doc="TCP connect timeout (wall)")
    reconnect_min: float = param(0.1, lo=0.01, hi=60.0, unit="s", doc="first reconnection delay (wall)")
    reconnect_max: float = param(5.0, lo=0.01, hi=600.0, unit="s", doc="longest reconnection delay (wall)")
    mode_timeout: float = param(1.0, lo=0.05, hi=30.0, unit="s", doc="wait for the PLC to answer a mode request")
    key_file: str = param("", doc="shared session key (the PLC's); empty: $ROS_HOME/quadrivio_plc.key")
    frame_id: str = param("base_link", doc="frame_id of /vehicle/state")
    plc_clock: str = param("auto", choices=("auto", "ros", "estimate"),
                           doc="the PLC's clock: ros (it is ROS time: the emulated PLC on sim time, a PLC "
                               "synchronised to this host), estimate (its own quartz: the offset is estimated "
                               "from the frames), auto (ros under /use_sim_time, else estimate)")


class PlcClock:
    """The PLC's clock (``plc_time`` of its STATE frames) on the receiver's clock, so that a
    measurement is stamped when it was made, not when it was read.

    A frame read late (a client that was descheduled or stopped, a backlog in the socket)
    is as old as its ``plc_time`` says. The offset is the smallest ``t_recv - plc_time``
    seen (the least-delayed frame is the truest), allowed to grow by ``drift`` s per s so
    that a PLC clock running slow is followed (a quartz is within 1e-4); a PLC clock that
    steps (a restart, the simulator's reset) or a receipt clock that moves back starts
    the estimate over. Stamps never lie ahead of their receipt.

    ``shared=True`` says the PLC's clock *is* the receiver's clock: the emulated PLC runs on
    sim time, which is ROS time. Its ``plc_time`` is then the stamp as it is. The estimate
    would be wrong there: a receiver on sim time reads ``/clock`` late now and then (by
    0.18 s at factor 3 while the stack starts), and the smallest ``t_recv - plc_time`` would
    keep that lag and stamp every state early by it for the next 15 minutes (2e-4 s/s).
    The estimate still runs, for a check: when even the least-delayed frame since the last
    start-over is more than ``max_step`` behind, or a frame is more than ``max_step`` ahead
    of its receipt, the two are not the same clock (a misconfiguration, or a receiver
    lagging by more than that), and the estimate's stamp is used (``mismatch`` counts those
    frames). A frame read late is behind, never ahead, so a backlog keeps its ``plc_time``.
    A shared stamp may lie ahead of a receipt made on a lagging ``/clock``, never by more
    than ``max_step``."""

    def __init__(self, drift: float = 2e-4, max_step: float = 1.0, shared: bool = False) -> None:
        self.drift, self.max_step, self.shared = drift, max_step, shared
        self.offset: Optional[float] = None
        self.last: Optional[Tuple[float, float]] = None  # (plc_time, t_recv) of the previous frame
        self.restarts = 0
        self.late = 0  # frames stamped more than 0.1 s before their receipt
        self.mismatch = 0  # shared: frames whose clock was not the receiver's (estimated instead)
        self.least: Optional[float] = None  # smallest t_recv - plc_time since the last start-over

    def reset(self) -> None:
        self.offset = self.last = self.least = None

    def stamp(self, plc_time: float, t_recv: float) -> float:
        """Receipt-clock time of the measurement ``plc_time`` read at ``t_recv``."""
        if not (math.isfinite(plc_time) and math.isfinite(t_recv)):
            return t_recv
        if self.last is not None:
            p0, r0 = self.last
            # the PLC's clock stepped (restart, reset) or ours moved back: start over
            if plc_time < p0 or t_recv < r0 or plc_time + self.offset > t_recv + self.max_step:
                self.reset()
                self.restarts += 1
        sample = t_recv - plc_time
        if self.offset is None:
            self.offset = sample
        else:
            grown = self.offset + self.drift * max(0.0, t_recv - self.last[1])
            self.offset = min(grown, sample)
        self.least = sample if self.least is None else min(self.least, sample)
        self.last = (plc_time, t_recv)
        t = min(t_recv, plc_time + self.offset)
        if self.shared:
            # not the offset: a /clock read late at the start leaves it below -max_step for minutes
            if self.least <= self.max_step and -sample <= self.max_step:
                t = plc_time
            else:
                self.mismatch += 1
        if t_recv - t > 0.1:
            self.late += 1
        return t


def mode_without_session(last_mode: int) -> int:
    """The mode to report while there is no session: HALT if the PLC was last seen in HALT,
    else SAFE, never a driving mode. Without a session the PLC brakes to SAFE (PROTOCOL.md,
    safety contract 2): its watchdog trips within 0.2 s of the last setpoint, and whatever it
    is in, no setpoint of ours reaches it. HALT is only left on request, so it is still HALT."""
    return protocol.MODE_HALT if last_mode == protocol.MODE_HALT else protocol.MODE_SAFE


@dataclass
class _Latest:
    t: float  # [s] ROS time of arrival
    speed: float
    handlebar: float
    brake: float


class Multiplexer:
    """Latest setpoint of each source, and the frames the PLC's mode wants from them.

    ``frames(mode, now)`` returns protocol messages: MANUAL forwards the manual source,
    AUTO the autonomous one, ASSISTED the autonomous handlebar plus the manual speed and
    brake (two frames), SAFE and HALT only a heartbeat. A source silent for longer than
    ``timeout`` is replaced by a stop (speed 0, brake ``stop_brake``, handlebar held).
    """

    def __init__(self, timeout: float, stop_brake: float) -> None:
        self.timeout = timeout
        self.stop_brake = stop_brake
        self.latest: Dict[int, Optional[_Latest]] = {protocol.SOURCE_MANUAL: None, protocol.SOURCE_AUTO: None}
        self.held_handlebar: Dict[int, float] = {protocol.SOURCE_MANUAL: 0.0, protocol.SOURCE_AUTO: 0.0}
        self.stale: Dict[int, bool] = {protocol.SOURCE_MANUAL: False, protocol.SOURCE_AUTO: False}

    def update(self, source: int, t: float, speed: float, handlebar: float, brake: float) -> None:
        self.latest[source] = _Latest(t, speed, handlebar, brake)

    def _setpoint(self, source: int, now: float) -> protocol.Setpoint:
        sp = self.latest[source]
        fresh = sp is not None and 0.0 <= now - sp.t <= self.timeout
        self.stale[source] = not fresh
        if not fresh:
            return protocol.Setpoint(source, 0.0, self.held_handlebar[source], self.stop_brake)
        self.held_handlebar[source] = sp.handlebar
        return protocol.Setpoint(source, sp.speed, sp.handlebar, sp.brake)

    def why_stale(self, source: int, now: float) -> str:
        """Why ``source`` is replaced by a stop at ``now``, for the log: none received yet,
        the last one too old (its age), or one stamped after ``now`` (the clock went back)."""
        sp = self.latest[source]
        if sp is None:
            return "none received yet"
        if now < sp.t:
            return f"the last one arrived at {sp.t:.3f} s, after now ({now:.3f} s): the clock went back"
        return f"the last one {now - sp.t:.2f} s ago (timeout {self.timeout:g} s)"

    def frames(self, mode: int, now: float) -> List[protocol.Message]:
        if mode == protocol.MODE_MANUAL:
            return [self._setpoint(protocol.SOURCE_MANUAL, now)]
        if mode == protocol.MODE_AUTO:
            return [self._setpoint(protocol.SOURCE_AUTO, now)]
        if mode == protocol.MODE_ASSISTED:
            return [self._setpoint(protocol.SOURCE_AUTO, now), self._setpoint(protocol.SOURCE_MANUAL, now)]
        return [protocol.Heartbeat()]

    def accepts(self, mode: int, source: int) -> bool:
        """Whether a new setpoint of ``source`` is forwarded at once in ``mode``."""
        return (mode == protocol.MODE_MANUAL and source == protocol.SOURCE_MANUAL) or \
               (mode == protocol.MODE_AUTO and source == protocol.SOURCE_AUTO) or mode == protocol.MODE_ASSISTED


@dataclass
class LinkStats:
    connects: int = 0  # sessions established
    disconnects: int = 0
    frames_sent: int = 0
    frames_received: int = 0
    states_received: int = 0
    acks_received: int = 0
    lost_frames: int = 0  # sequence gaps in the PLC's frames
    unanswered: int = 0  # our frames never acknowledged (dropped from the RTT table)
    refused: int = 0
    stale_acks: int = 0  # frames the PLC reported as not advancing its sequence


class PlcLink:
    """TCP link to the PLC (see module docstring).

    Callbacks run in the thread that calls :meth:`poll`: ``on_state(State)``,
    ``on_ack(Ack)``, ``on_event(level, text)`` for connection events and rejected input
    (level "info", "warn", or "notice": a warning said once, never to be throttled).
    """

    RTT_WINDOW = 100_000  # round-trip times kept for the percentiles (10 min at 2 x 50 Hz fits)

    def __init__(self, host: str, port: int, *, connect_timeout: float = 1.0, reconnect_min: float = 0.1,
                 reconnect_max: float = 5.0, on_state: Callable[[protocol.State], None] = lambda s: None,
                 on_ack: Callable[[protocol.Ack], None] = lambda a: None,
                 on_event: Callable[[str, str], None] = lambda level, text: None,
                 clock: Callable[[], float] = time.monotonic, key_file: str = "",
                 key: Optional[bytes] = None) -> None:
        self.host, self.port = host, port
        self.key_file, self.key = key_file, key
        self.connect_timeout = connect_timeout
        self.reconnect_min, self.reconnect_max = reconnect_min, reconnect_max
        self.on_state, self.on_ack, self.on_event = on_state, on_ack, on_event
        self.clock = clock
        self.sel = selectors.DefaultSelector()
        self.sock: Optional[socket.socket] = None
        self.session = False  # the PLC accepted our AUTH: frames may be sent
        self._key = b""
        self._key_checked = b""  # the key whose file was last checked for key_warnings
        self.opened = 0.0  # clock at TCP connect (HELLO and AUTH must complete within connect_timeout)
        self.lock = threading.Lock()  # socket, out buffer, sequence numbers, sent times
        self.out = bytearray()
        self.seq = 0
        self.sent_at: Dict[int, float] = {}
        self.ack_callbacks: Dict[int, Callable[[protocol.Ack], None]] = {}
        self.rtts: Deque[float] = deque(maxlen=self.RTT_WINDOW)
        self.decoder = protocol.FrameDecoder()
        self.peer_seq: Optional[int] = None
        self.stats = LinkStats()
        self.backoff = reconnect_min
        self.next_attempt = 0.0
        self.last_rx = -math.inf
        self.last_error = ""
        # A send that failed in another thread: the I/O thread reads what the PLC sent
        # before the connection broke, then drops it (see ``poll``)
        self.write_error = ""

    @property
    def connected(self) -> bool:
        """Whether a session with the PLC is established (not merely a TCP connection)."""
        return self.session

    # ------------------------------------------------------------ connecting
    def _fail(self, why: str) -> None:
        self.last_error = why
        self.on_event("warn", f"{why}; next attempt in {self.backoff:.1f} s")
        self.next_attempt = self.clock() + self.backoff
        self.backoff = min(self.backoff * 2.0, self.reconnect_max)

    def _connect(self) -> None:
        now = self.clock()
        if now < self.next_attempt:
            return
        try:
            key = self.key if self.key is not None else protocol.load_key(self.key_file)
        except protocol.KeyFileError as exc:
            self._fail(str(exc))
            return
        if self.key is None and key != self._key_checked:
            self._key_checked = key
            for warning in protocol.key_warnings(self.key_file, key):
                self.on_event("notice", warning)  # once per key, not throttled away by the link's warnings
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.connect_timeout)
        except OSError as exc:
            self._fail(f"cannot connect to the PLC at {self.host}:{self.port}: {exc.strerror or exc}")
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self.lock:
            self.sock = sock
            self.session = False
            self.out.clear()
            self.write_error = ""
            self.sent_at.clear()
            self.ack_callbacks.clear()
        self._key = key
        self.decoder = protocol.FrameDecoder()
        self.peer_seq = None
        self.sel.register(sock, selectors.EVENT_READ)
        self.opened = self.last_rx = now

    def _on_hello(self, hello: protocol.Hello) -> None:
        with self.lock:
            if self.sock is None or self.session:
                return
            seq = self.seq
            self.seq = (self.seq + 1) & 0xFFFF
            self.out += protocol.encode(protocol.Auth(protocol.auth_mac(self._key, hello.nonce)), seq)
            error = self._flush_locked()
        if error:
            self._drop(error)

    def _on_session(self) -> None:
        with self.lock:
            self.session = True
        self.stats.connects += 1
        self.backoff = self.reconnect_min
        self.last_error = ""
        self.on_event("info", f"session with the PLC at {self.host}:{self.port} established")

    def _drop(self, why: str) -> None:
        with self.lock:
            sock, self.sock = self.sock, None
            was_session, self.session = self.session, False
            self.write_error = ""
        if sock is None:
            return
        try:
            self.sel.unregister(sock)
        except (KeyError, ValueError):
            pass
        sock.close()
        if was_session:
            self.stats.disconnects += 1
            self._fail(f"PLC link lost ({why})")
        else:
            self._fail(f"no session with the PLC at {self.host}:{self.port} ({why})")

    def close(self) -> None:
        self._drop("closed")
        self.sel.close()

    # --------------------------------------------------------------- sending
    def send(self, msg: protocol.Message, on_ack: Optional[Callable[[protocol.Ack], None]] = None) -> Optional[int]:
        """Send ``msg``; returns its sequence number, None when not connected.

        ``on_ack`` is called (in the polling thread) with the PLC's ACK of this frame; it is
        registered before the frame leaves, so a fast answer cannot be missed.
        """
        with self.lock:
            if self.sock is None or not self.session:
                return None
            seq = self.seq
            self.seq = (self.seq + 1) & 0xFFFF
            self.out += protocol.encode(msg, seq)
            self.sent_at[seq] = self.clock()
            if on_ack is not None:
                self.ack_callbacks[seq] = on_ack
            if len(self.sent_at) > 1000:  # never answered: forget the oldest
                oldest = next(iter(self.sent_at))
                del self.sent_at[oldest]
                self.ack_callbacks.pop(oldest, None)
                self.stats.unanswered += 1
            self.stats.frames_sent += 1
            error = self._flush_locked()
            if error and not self.write_error:
                # Not dropped here: the socket may still hold the PLC's last frames (a
                # client stopped by a signal and resumed finds its connection replaced, and
                # its states say the watchdog braked). The I/O thread reads them first.
                self.write_error = error
        return seq

    def _flush_locked(self) -> str:
        try:
            while self.out:
                n = self.sock.send(self.out)  # type: ignore[union-attr]
                del self.out[:n]
        except BlockingIOError:
            if len(self.out) > 1 << 20:
                return "the PLC does not read (1 MiB of frames queued)"
        except OSError as exc:
            return str(exc)
        return ""

    # ------------------------------------------------------------- receiving
    def poll(self, timeout: float) -> None:
        """Connect if needed, then handle incoming frames for at most ``timeout`` s."""
        if self.sock is None:
            self._connect()
            if self.sock is None:
                wait = max(0.0, min(timeout, self.next_attempt - self.clock()))
                if wait > 0:
                    threading.Event().wait(wait)
                return
        for _key, _ in self.sel.select(timeout=timeout):
            self._read()
        if self.sock is not None and not self.session and self.clock() - self.opened > self.connect_timeout:
            self._drop(f"no HELLO/AUTH answer within {self.connect_timeout} s (not a version-{protocol.VERSION} "
                       f"Quadrivio PLC?)")
        with self.lock:
            error = self._flush_locked() if self.sock is not None and self.out else ""
            error, self.write_error = error or self.write_error, ""
        if error:
            for _ in range(1024):  # what the PLC sent before the connection broke, then the drop
                if not self._read():
                    break
            self._drop(error)

    def _read(self) -> bool:
        """Read and handle what the socket holds; whether anything was read."""
        sock = self.sock
        if sock is None:
            return False
        try:
            data = sock.recv(65536)
        except BlockingIOError:
            return False
        except OSError as exc:
            self._drop(str(exc))
            return False
        if not data:
            self._drop("connection closed by the PLC")
            return False
        now = self.clock()
        self.last_rx = now
        for seq, msg in self.decoder.feed(data):
            self.stats.frames_received += 1
            if self.peer_seq is not None:
                gap = (seq - self.peer_seq - 1) & 0xFFFF
                if gap:
                    self.stats.lost_frames += gap
                    self.on_event("warn", f"{gap} PLC frame(s) lost before seq {seq}")
            self.peer_seq = seq
            if isinstance(msg, protocol.State):
                self.stats.states_received += 1
                self.on_state(msg)
            elif isinstance(msg, protocol.Hello):
                self._on_hello(msg)
            elif isinstance(msg, protocol.Ack) and not self.session:
                if msg.acked_type == protocol.Auth.TYPE and msg.status == protocol.OK:
                    self._on_session()
            elif isinstance(msg, protocol.Ack):
                self.stats.acks_received += 1
                if msg.status == protocol.STALE:
                    self.stats.stale_acks += 1
                with self.lock:
                    sent = self.sent_at.pop(msg.ack_seq, None)
                    callback = self.ack_callbacks.pop(msg.ack_seq, None)
                if sent is not None:
                    self.rtts.append(now - sent)
                if callback is not None:
                    callback(msg)
                self.on_ack(msg)
            elif isinstance(msg, protocol.Refused):
                self.stats.refused += 1
                self._drop(f"refused by the PLC: {msg.text}")
                return False
        for problem in self.decoder.pop_problems():
            self.on_event("warn", f"frame from the PLC rejected ({problem}); skipped")
        return True

    def rtt_percentiles(self, *qs: float) -> Tuple[float, ...]:
        """Round-trip time percentiles [s] over the last frames (NaN before any)."""
        data = sorted(self.rtts)
        if not data:
            return tuple(math.nan for _ in qs)
        return tuple(data[min(len(data) - 1, int(q / 100.0 * len(data)))] for q in qs)
