"""The emulated X20 PLC: operating modes, setpoint gating, watchdog, low-level loops,
and its TCP server (paper section 3.3 and Fig. 5). The safety contract it enforces is
written in ``quadrivio_plc/PROTOCOL.md`` ("Safety contract").

:class:`PlcLogic` is the PLC program, driven by sim time. It mirrors the real
vehicle's modes::

    HALT --request--> SAFE --request--> MANUAL | ASSISTED | AUTO
    any  --request--> HALT;   MANUAL | ASSISTED | AUTO --request--> SAFE or another of them
    MANUAL | ASSISTED | AUTO --no fresh setpoint for `watchdog` s--> SAFE (+ FAULT_WATCHDOG)
    MANUAL | ASSISTED | AUTO --session lost--> SAFE (+ FAULT_LINK)

and accepts setpoints only from the source matching the mode: MANUAL takes everything
from the manual source, AUTO from the autonomous one, ASSISTED the handlebar from the
autonomous source and speed and brake from the manual one (a safety driver on the
throttle). Only an accepted setpoint of the source the mode drives from feeds the
watchdog; heartbeats, mode requests, refused or non-finite setpoints never do. SAFE
holds the brake; HALT also freezes the handlebar servo.

:class:`PlcServer` is its transport: a non-blocking TCP server polled from the simulator
loop, so frames are handled between physics steps. Every connection starts with a HELLO
challenge; only a connection that answers it with the shared key becomes the session,
one at a time, and only the session's frames with advancing sequence numbers reach the
program. Work per poll is bounded (bytes read per connection, pending connections), and
rejected input is counted and logged at most once a second per kind.
"""

from __future__ import annotations

import errno
import ipaddress
import math
import selectors
import socket
import time
from dataclasses import dataclass, field
from typing import Callable, Dict, List, Optional, Tuple

from quadrivio_config import param
from quadrivio_plc import protocol

from .actuators import Actuation, LowLevelControl
from .noise import LatencyParams
from .standstill import StandstillMonitor, StandstillParams


@dataclass(frozen=True)
class PlcParams:
    host: str = param("127.0.0.1", doc="address the emulated PLC listens on (loopback by default)")
    port: int = param(protocol.DEFAULT_PORT, lo=0, hi=65535, doc="TCP port (0: any free port)")
    cycle: float = param(0.01, lo=0.001, hi=0.1, unit="s", doc="PLC cycle of the low-level loops")
    state_rate: float = param(50.0, lo=1.0, hi=1000.0, unit="Hz", doc="rate of STATE frames to the client")
    watchdog: float = param(0.2, lo=0.01, hi=10.0, unit="s",
                            doc="brake and go to SAFE when no fresh setpoint of the mode's source arrives for this long")
    session_timeout: float = param(1.0, lo=0.05, hi=60.0, unit="s",
                                   doc="end the session when no valid frame at all arrives for this long (PLC time)")
    auth_timeout: float = param(2.0, lo=0.1, hi=60.0, unit="s",
                                doc="close a connection that has not authenticated within this (wall time)")
    max_pending: int = param(4, lo=1, hi=64, doc="connections allowed to be authenticating at once; when all are "
                                                "taken, the oldest one past auth_grace makes way for a new one")
    auth_grace: float = param(0.2, lo=0.01, hi=10.0, unit="s",
                              doc="an authenticating connection is never evicted for a newer one before this "
                                  "(wall time: the key holder answers HELLO within one round trip)")
    max_pending_per_source: int = param(2, lo=1, hi=64,
                                        doc="authenticating connections one address may hold, except client_host's "
                                            "and the last session's")
    client_host: str = param("127.0.0.1", doc="the PLCClient's address (the vehicle PC's on the real PLC): not held "
                                              "to max_pending_per_source")
    key_file: str = param("", doc="shared session key; empty: $ROS_HOME/quadrivio_plc.key (created if missing)")
    initial_mode: str = param("SAFE", choices=("HALT", "SAFE"), doc="mode at power-on")
    hold_brake: float = param(1.0, lo=0.0, hi=1.0, doc="brake applied in SAFE and HALT")
    standstill: StandstillParams = param(StandstillParams(),
                                         doc="what a driving mode needs to be entered from SAFE: the wheel and the "
                                             "accelerometer at rest for a hold time (PROTOCOL.md, Re-entry)")
    latency: LatencyParams = param(LatencyParams(0.002, 0.0005),
                                   doc="the link's delay of STATE frames (the vehicle's X20 over Ethernet, its task "
                                       "cycle included); a frame leaves at the first physics step at or after "
                                       "plc_time + delay")


ALLOWED = {
    protocol.MODE_HALT: {protocol.MODE_HALT, protocol.MODE_SAFE},
    protocol.MODE_SAFE: {protocol.MODE_HALT, protocol.MODE_SAFE, protocol.MODE_MANUAL, protocol.MODE_ASSISTED, protocol.MODE_AUTO},
}
DRIVING = (protocol.MODE_MANUAL, protocol.MODE_ASSISTED, protocol.MODE_AUTO)
LATCHED = protocol.FAULT_WATCHDOG | protocol.FAULT_LINK  # faults that stay until the client acknowledges them (RESET)
for _m in DRIVING:
    ALLOWED[_m] = {protocol.MODE_HALT, protocol.MODE_SAFE, *DRIVING}


def _roles(mode: int, source: int) -> Tuple[bool, bool]:
    """(takes speed and brake, takes handlebar) from ``source`` in ``mode``."""
    motion = (mode == protocol.MODE_MANUAL and source == protocol.SOURCE_MANUAL) or \
             (mode == protocol.MODE_AUTO and source == protocol.SOURCE_AUTO) or \
             (mode == protocol.MODE_ASSISTED and source == protocol.SOURCE_MANUAL)
    handlebar = (mode == protocol.MODE_MANUAL and source == protocol.SOURCE_MANUAL) or \
                (mode in (protocol.MODE_AUTO, protocol.MODE_ASSISTED) and source == protocol.SOURCE_AUTO)
    return motion, handlebar


class PlcLogic:
    """The PLC program (see module docstring). Times are PLC clock seconds (sim time)."""

    def __init__(self, params: PlcParams, control: LowLevelControl) -> None:
        self.p = params
        self.control = control
        self.standstill = StandstillMonitor(params.standstill)
        self.reset(0.0)

    def reset(self, t: float) -> None:
        self.mode = protocol.MODE_BY_NAME[self.p.initial_mode]
        self.faults = 0
        self.last_rx = -math.inf  # last valid frame of the session
        self.fresh_motion = -math.inf  # last accepted speed/brake setpoint of the mode's source
        self.fresh_handlebar = -math.inf  # last accepted handlebar setpoint of the mode's source
        self.last_seq = 0
        self.sp_speed = 0.0
        self.sp_handlebar = 0.0
        self.sp_brake = self.p.hold_brake
        self.watchdog_trips = 0
        self.link_losses = 0
        self.control.reset()
        self.standstill.reset(t)
        self.events: List[Tuple[str, str]] = []  # (kind, text): the node rate-limits them by kind

    @property
    def fresh_since(self) -> float:
        """PLC time of the oldest setpoint role the mode depends on (what the watchdog checks)."""
        return min(self.fresh_motion, self.fresh_handlebar)

    def _stop(self, mode: int, fault: int, why: str, t: float) -> None:
        """Leave a driving mode for SAFE or HALT: brake, handlebar held, setpoints cleared."""
        self.events.append(("stop", f"{why} ({protocol.mode_name(self.mode)} -> {protocol.mode_name(mode)})"))
        self.mode = mode
        self.faults |= fault
        self.sp_speed, self.sp_brake = 0.0, self.p.hold_brake
        self.sp_handlebar = self.control.handlebar.angle
        self.standstill.braking(t)

    # -------------------------------------------------------------- frames
    def handle(self, t: float, seq: int, msg: protocol.Message) -> Optional[protocol.Ack]:
        """React to one valid frame of the authenticated session; returns the ACK to send."""
        self.last_rx = t
        self.last_seq = seq
        if isinstance(msg, protocol.ModeRequest):
            return protocol.Ack(seq, msg.TYPE, self.request_mode(msg.mode, t), self.mode)
        if isinstance(msg, protocol.Setpoint):
            return protocol.Ack(seq, msg.TYPE, self.setpoint(msg.source, msg.speed, msg.handlebar, msg.brake, t), self.mode)
        if isinstance(msg, protocol.Reset):
            return protocol.Ack(seq, msg.TYPE, self.acknowledge(msg.faults, t), self.mode)
        if isinstance(msg, (protocol.Heartbeat, protocol.Auth)):
            return protocol.Ack(seq, msg.TYPE, protocol.OK, self.mode)
        return None  # PLC-to-client messages coming back: ignored

    def acknowledge(self, faults: int, t: float) -> int:
        """RESET: the client acknowledges latched faults (WATCHDOG, LINK), at a verified standstill only."""
        latched = self.faults & LATCHED & faults
        if not latched:
            return protocol.OK
        ok, why = self.standstill.verified(t)
        if not ok:
            self.events.append(("refused", f"refused to acknowledge {protocol.fault_names(latched)}: not at standstill ({why})"))
            return protocol.NOT_AT_STANDSTILL
        self.faults &= ~latched
        self.events.append(("acknowledged", f"{protocol.fault_names(latched)} acknowledged"))
        return protocol.OK

    def request_mode(self, mode: int, t: float = 0.0) -> int:
        if mode not in protocol.MODE_NAMES or mode not in ALLOWED[self.mode]:
            self.events.append(("refused", f"refused mode change {protocol.mode_name(self.mode)} -> {protocol.mode_name(mode)}"))
            return protocol.BAD_TRANSITION
        if mode in DRIVING and self.mode not in DRIVING:
            # Re-entry (PROTOCOL.md): a stop with a fault is acknowledged first, and the
            # vehicle must stand, verified by the wheel and the accelerometer over a hold
            # time (a locked wheel reads 0 while the body slides on).
            if self.faults & LATCHED:
                self.events.append(("refused", f"refused mode change {protocol.mode_name(self.mode)} -> "
                                               f"{protocol.mode_name(mode)}: {protocol.fault_names(self.faults & LATCHED)} "
                                               f"not acknowledged (RESET)"))
                return protocol.NOT_ACKNOWLEDGED
            ok, why = self.standstill.verified(t)
            if not ok:
                self.events.append(("refused", f"refused mode change {protocol.mode_name(self.mode)} -> "
                                               f"{protocol.mode_name(mode)}: not at standstill ({why})"))
                return protocol.NOT_AT_STANDSTILL
        if mode != self.mode:
            if mode in DRIVING and self.mode not in DRIVING:
                # Start from standstill with the handlebar where it is; the client has one
                # watchdog period from now to send its first setpoint.
                self.events.append(("mode", f"mode {protocol.mode_name(self.mode)} -> {protocol.mode_name(mode)}"))
                self.sp_speed, self.sp_brake = 0.0, 0.0
                self.sp_handlebar = self.control.handlebar.angle
                self.fresh_motion = self.fresh_handlebar = t
                self.mode = mode
            elif mode in DRIVING:
                # Between driving modes: the new source must be fresh within what is left
                # of the current watchdog period (a mode change never feeds the watchdog).
                self.events.append(("mode", f"mode {protocol.mode_name(self.mode)} -> {protocol.mode_name(mode)}"))
                self.fresh_motion = self.fresh_handlebar = self.fresh_since
                self.mode = mode
            elif self.mode in DRIVING:
                self._stop(mode, 0, "stop requested", t)
            else:
                self.events.append(("mode", f"mode {protocol.mode_name(self.mode)} -> {protocol.mode_name(mode)}"))
                self.mode = mode
        self.faults = (self.faults | protocol.FAULT_ESTOP) if mode == protocol.MODE_HALT else (self.faults & ~protocol.FAULT_ESTOP)
        return protocol.OK

    def setpoint(self, source: int, speed: float, handlebar: float, brake: float,
                 t: Optional[float] = None) -> int:
        """Apply a setpoint; an accepted one at PLC time ``t`` feeds the watchdog for its roles."""
        if not protocol.finite(speed, handlebar, brake):
            return protocol.BAD_VALUE
        if self.mode not in DRIVING:
            return protocol.NOT_ACCEPTING
        takes_motion, takes_handlebar = _roles(self.mode, source)
        if not (takes_motion or takes_handlebar):
            return protocol.WRONG_SOURCE
        c_speed, c_handlebar, c_brake, clamped = self.control.clamp(speed, handlebar, brake)
        if takes_motion:
            self.sp_speed, self.sp_brake = c_speed, c_brake
            if t is not None:
                self.fresh_motion = t
        if takes_handlebar:
            self.sp_handlebar = c_handlebar
            if t is not None:
                self.fresh_handlebar = t
        if clamped:
            self.faults |= protocol.FAULT_SETPOINT_CLAMPED
            self.events.append(("clamped", f"setpoint clamped: speed {speed:.3f} -> {c_speed:.3f} m/s, handlebar "
                               f"{handlebar:.3f} -> {c_handlebar:.3f} rad, brake {brake:.3f} -> {c_brake:.3f}"))
            return protocol.CLAMPED
        self.faults &= ~protocol.FAULT_SETPOINT_CLAMPED
        return protocol.OK

    def force_auto(self, t: float) -> None:
        """Debug path: enter AUTO from any mode (simulation test hook, never on the real PLC)."""
        if self.mode != protocol.MODE_AUTO:
            self.events.append(("mode", f"debug setpoint: mode {protocol.mode_name(self.mode)} -> AUTO"))
            if self.mode not in DRIVING:
                self.sp_handlebar = self.control.handlebar.angle
            self.mode = protocol.MODE_AUTO
            self.faults &= ~(protocol.FAULT_WATCHDOG | protocol.FAULT_ESTOP | protocol.FAULT_LINK)
        self.last_rx = self.fresh_motion = self.fresh_handlebar = t

    def link_lost(self, t: float, why: str) -> None:
        """The session ended (closed, failed, silent or replaced): a driving PLC brakes to SAFE."""
        self.link_losses += 1
        if self.mode in DRIVING:
            self._stop(protocol.MODE_SAFE, protocol.FAULT_LINK, f"link lost ({why}): braking", t)

    # --------------------------------------------------------------- cycle
    def cycle(self, t: float, wheel_speed: float, wheel_rate: float, accel_x: float = math.nan) -> Actuation:
        """One PLC cycle at time ``t``: standstill monitor, watchdog, then the low-level loops.
        ``accel_x``: the PLC accelerometer's specific force along the body's x axis [m/s^2]
        (NaN: none, standstill from the wheel and slide_timeout alone)."""
        self.standstill.update(t, wheel_speed, accel_x)
        for ev in self.standstill.pop_events():
            self.events.append(("standstill", ev))
        if self.mode in DRIVING and t - self.fresh_since > self.p.watchdog:
            self.watchdog_trips += 1
            self._stop(protocol.MODE_SAFE, protocol.FAULT_WATCHDOG,
                       f"watchdog: no fresh setpoint for {t - self.fresh_since:.3f} s > {self.p.watchdog} s, braking", t)
        if self.mode in DRIVING:
            return self.control.step(self.sp_speed, self.sp_handlebar, self.sp_brake, wheel_speed, wheel_rate)
        handlebar = None if self.mode == protocol.MODE_HALT else self.control.handlebar.angle
        return self.control.step(0.0, handlebar, self.p.hold_brake, wheel_speed, wheel_rate)

    def state(self, t: float, wheel_speed: float) -> protocol.State:
        out = self.control.out
        return protocol.State(t, self.mode, self.faults, self.last_seq, wheel_speed, out.handlebar, out.throttle,
                       out.brake, self.sp_speed, self.sp_handlebar)

    def pop_events(self) -> List[Tuple[str, str]]:
        """(kind, text) of what happened since the last call; kinds: stop, mode, refused,
        acknowledged, clamped, standstill."""
        ev, self.events = self.events, []
        return ev


class EventThrottle:
    """At most ``burst`` lines per kind of event in any ``interval`` wall seconds; the rest
    counted, and the count said on the kind's next line. A flood of valid frames (a refused
    mode 2,000 times a second, HALT/SAFE alternation, clamped setpoints) costs the log a few
    lines a second, and a rare event (a watchdog trip) is always said at once."""

    def __init__(self, interval: float = 1.0, burst: int = 3, clock: Callable[[], float] = time.monotonic) -> None:
        self.interval, self.burst, self.clock = interval, burst, clock
        self.recent: Dict[str, List[float]] = {}
        self.suppressed: Dict[str, int] = {}

    def admit(self, kind: str, text: str) -> Optional[str]:
        """The line to log for this event, or None when it is only counted."""
        now = self.clock()
        times = [t for t in self.recent.get(kind, ()) if now - t < self.interval]
        if len(times) >= self.burst:
            self.recent[kind] = times
            self.suppressed[kind] = self.suppressed.get(kind, 0) + 1
            return None
        times.append(now)
        self.recent[kind] = times
        n = self.suppressed.pop(kind, 0)
        return text + (f" (and {n} more {kind} events since the last report)" if n else "")


@dataclass
class _Conn:
    sock: socket.socket
    peer: str
    nonce: bytes
    opened: float  # wall time of accept
    host: str = ""
    seq: int = 0  # sequence number of our next frame on this connection
    decoder: protocol.FrameDecoder = field(default_factory=protocol.FrameDecoder)
    out: bytearray = field(default_factory=bytearray)
    authed: bool = False
    last_seq: Optional[int] = None
    last_rx: float = -math.inf  # PLC time of the last valid frame


@dataclass
class ServerStats:
    sessions: int = 0
    refused: int = 0  # connections refused: busy, too many pending, failed or missing authentication
    evicted: int = 0  # authenticating connections closed to make way for a newer one
    auth_failures: int = 0
    stale_frames: int = 0  # frames whose sequence number did not advance (not acted on)
    disconnects: int = 0
    frames: int = 0  # valid frames of sessions
    bad_frames: Dict[str, int] = field(default_factory=dict)  # by reason, every connection


class PlcServer:
    """Non-blocking TCP transport of :class:`PlcLogic` (see module docstring).

    ``clock`` returns the PLC time (sim time) at which incoming frames are handled.
    ``log(level, text)`` receives connection events and (rate-limited) rejected input.
    ``key`` is the shared session key (bytes); None reads or creates ``params.key_file``.
    """

    READ_CHUNK = 4096  # bytes read per connection and poll: the parser's work per poll is bounded
    LOG_INTERVAL = 1.0  # [s wall] at most one log line per kind of rejection and interval
    GARBAGE_BEFORE_AUTH = 64  # bytes of rejected input an unauthenticated connection may send

    def __init__(self, logic: PlcLogic, host: str, port: int, clock: Callable[[], float],
                 log: Callable[[str, str], None], key: Optional[bytes] = None,
                 wall: Callable[[], float] = time.monotonic) -> None:
        self.logic = logic
        self.p = logic.p
        self.clock = clock
        self.wall = wall
        self.log = log
        self.key = key if key is not None else protocol.ensure_key(self.p.key_file)
        self.sel = selectors.DefaultSelector()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((host, port))
        except OSError as exc:
            self.listener.close()
            raise OSError(exc.errno, f"emulated PLC cannot listen on {host}:{port}: {exc.strerror}") from exc
        self.listener.listen(8)
        self.listener.setblocking(False)
        self.address: Tuple[str, int] = self.listener.getsockname()
        self.sel.register(self.listener, selectors.EVENT_READ, None)
        # wakeup() ends a poll from another thread (lockstep waits for reports and frames at once)
        self._wake_r, self._wake_w = socket.socketpair()
        self._wake_r.setblocking(False)
        self._wake_w.setblocking(False)
        self.sel.register(self._wake_r, selectors.EVENT_READ, _WAKE)
        self.session: Optional[_Conn] = None
        self.pending: Dict[socket.socket, _Conn] = {}
        self.listening = True  # the listener is polled (not while every pending slot is within its grace)
        self.known_hosts = {self.p.client_host}  # exempt from max_pending_per_source (+ the last session's)
        self.frames_sent = 0
        self.states_sent = self.acks_sent = 0  # in a session (lockstep counts them)
        self.stats = ServerStats()
        self._logged: Dict[str, float] = {}
        self._suppressed: Dict[str, int] = {}

    @property
    def connected(self) -> bool:
        """Whether an authenticated session is established."""
        return self.session is not None

    @property
    def peer(self) -> str:
        return self.session.peer if self.session is not None else ""

    # ------------------------------------------------------------- logging
    def _log_limited(self, kind: str, level: str, text: str) -> None:
        now = self.wall()
        if now - self._logged.get(kind, -math.inf) < self.LOG_INTERVAL:
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return
        n = self._suppressed.pop(kind, 0)
        self._logged[kind] = now
        self.log(level, text + (f" (and {n} more like it since the last report)" if n else ""))

    # ------------------------------------------------------------- polling
    def poll(self, timeout: float = 0.0) -> None:
        """Handle pending connections and frames, waiting at most ``timeout`` wall seconds."""
        wait = self._listen_when_a_slot_can_be_had()
        if wait is not None:
            timeout = min(timeout, wait)
        for key, _ in self.sel.select(timeout=max(0.0, timeout)):
            if key.data is None:
                self._accept()
            elif key.data is _WAKE:
                try:
                    while self._wake_r.recv(4096):
                        pass
                except (BlockingIOError, InterruptedError):
                    pass
            else:
                self._read(key.data)
        self._expire()

    def wakeup(self) -> None:
        """End the current or next :meth:`poll` early (thread-safe)."""
        try:
            self._wake_w.send(b"w")
        except OSError:  # full (a wake-up is pending anyway) or closed
            pass

    def _expire(self) -> None:
        s = self.session
        if s is not None and self.clock() - s.last_rx > self.p.session_timeout:
            self._end_session(f"no valid frame for {self.clock() - s.last_rx:.2f} s > session_timeout "
                              f"{self.p.session_timeout} s")
        if self.pending:
            now = self.wall()
            for conn in [c for c in self.pending.values() if now - c.opened > self.p.auth_timeout]:
                self._refuse(conn, protocol.NOT_AUTHENTICATED, f"no authentication within {self.p.auth_timeout} s")

    def _listen_when_a_slot_can_be_had(self) -> Optional[float]:
        """Accept new connections only when one can be served: a free pending slot, or an
        authenticating connection past its grace to evict. Otherwise they wait in the
        kernel's backlog, in arrival order (a stranger churning its own connections cannot
        jump ahead of the key holder's), and the listener is not polled: a readable listener
        that is not accepted from would turn every poll into a busy loop. Returns the wall
        time until a slot frees by age (None: not full)."""
        wait = None
        if len(self.pending) >= self.p.max_pending:
            oldest = min(c.opened for c in self.pending.values())
            wait = oldest + self.p.auth_grace - self.wall()
        can = wait is None or wait <= 0.0
        if can != self.listening:
            if can:
                self.sel.register(self.listener, selectors.EVENT_READ, None)
            else:
                self.sel.unregister(self.listener)
            self.listening = can
        return None if wait is None else max(0.0, wait)

    def _accept(self) -> None:
        try:
            sock, addr = self.listener.accept()
        except OSError:
            return
        peer = f"{addr[0]}:{addr[1]}"
        sock.setblocking(False)
        conn = _Conn(sock, peer, protocol.new_nonce(), self.wall(), str(addr[0]))
        if conn.host not in self.known_hosts:
            mine = sum(1 for c in self.pending.values() if c.host == conn.host)
            if mine >= self.p.max_pending_per_source:
                self._refuse(conn, protocol.BUSY, f"{conn.host} already has {mine} connections authenticating")
                return
        if len(self.pending) >= self.p.max_pending:
            # Make way: the oldest authenticating connection has had its grace (the listener
            # is only polled then) and a key holder would have answered HELLO long ago.
            oldest = min(self.pending.values(), key=lambda c: c.opened)
            self.stats.evicted += 1
            self._refuse(oldest, protocol.BUSY, f"no authentication after {self.wall() - oldest.opened:.2f} s while "
                                         f"{len(self.pending)} connections were authenticating: evicted for a "
                                         f"new one")
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.pending[sock] = conn
        self.sel.register(sock, selectors.EVENT_READ, conn)
        self._send(conn, protocol.Hello(conn.nonce, self.p.watchdog, self.p.session_timeout))
        self._flush(conn)

    def _close(self, conn: _Conn) -> None:
        self.pending.pop(conn.sock, None)
        try:
            self.sel.unregister(conn.sock)
        except (KeyError, ValueError):
            pass
        conn.sock.close()

    def _refuse(self, conn: _Conn, reason: int, why: str) -> None:
        """Tell a connection why it is not served (REFUSED), then close it."""
        self.stats.refused += 1
        self._log_limited(f"refused {reason}", "warn", f"refused PLC connection from {conn.peer}: {why}")
        try:
            conn.sock.send(protocol.encode(protocol.Refused(reason, why), conn.seq))
        except OSError:
            pass
        self._close(conn)

    def _end_session(self, why: str) -> None:
        s = self.session
        if s is None:
            return
        self.logic.link_lost(self.clock(), why)  # braked before anything else can connect
        self.session = None
        self.stats.disconnects += 1
        self.log("warn", f"PLC session with {s.peer} ended: {why}")
        self._close(s)

    def _read(self, conn: _Conn) -> None:
        try:
            data = conn.sock.recv(self.READ_CHUNK)
        except BlockingIOError:
            return
        except OSError as exc:
            data, error = b"", str(exc)
        else:
            error = "connection closed"
        if not data:
            if conn is self.session:
                self._end_session(error)
            else:
                self._close(conn)
            return
        t = self.clock()
        frames = conn.decoder.feed(data)
        for reason, n in conn.decoder.stats.errors.items():
            self.stats.bad_frames[reason] = self.stats.bad_frames.get(reason, 0) + n
        conn.decoder.stats.errors.clear()
        problems = conn.decoder.pop_problems()
        if problems:
            self._log_limited("bad frames", "warn", f"PLC frames from {conn.peer} rejected and skipped: "
                                                    f"{'; '.join(problems)}")
        if not conn.authed:
            frames = self._authenticate(conn, frames, t)
        self._handle(conn, frames, t)

    def _handle(self, conn: _Conn, frames, t: float) -> None:
        """Frames of the session: only those whose sequence number advances reach the program."""
        for seq, msg in frames:
            if self.session is not conn:
                return
            if not protocol.seq_advanced(seq, conn.last_seq):
                self.stats.stale_frames += 1
                self._log_limited("stale", "warn", f"PLC frame seq {seq} from {conn.peer} does not advance "
                                                   f"(last {conn.last_seq}): replayed or reordered, ignored")
                self._send(conn, protocol.Ack(seq, getattr(msg, "TYPE", 0), protocol.STALE, self.logic.mode))
                self.acks_sent += 1
                continue
            conn.last_seq, conn.last_rx = seq, t
            self.stats.frames += 1
            ack = self.logic.handle(t, seq, msg)
            if ack is not None:
                self._send(conn, ack)
                self.acks_sent += 1
        self._flush(conn)

    def _authenticate(self, conn: _Conn, frames, t: float):
        """The first frame of a connection must be AUTH with the right MAC; returns the frames
        left to handle once it is the session (none otherwise)."""
        if conn.decoder.stats.bytes_skipped > self.GARBAGE_BEFORE_AUTH:
            self._refuse(conn, protocol.NOT_AUTHENTICATED, "unframed input before authentication")
            return []
        if not frames:
            return []
        seq, msg = frames[0]
        if not isinstance(msg, protocol.Auth) or not protocol.auth_ok(self.key, conn.nonce, msg.mac):
            self.stats.auth_failures += 1
            what = "wrong key" if isinstance(msg, protocol.Auth) else f"{type(msg).__name__} before AUTH"
            self._refuse(conn, protocol.NOT_AUTHENTICATED, f"authentication failed ({what})")
            return []
        s = self.session
        if s is not None and t - s.last_rx <= self.p.watchdog:
            self._refuse(conn, protocol.BUSY, f"a session with {s.peer} is active")
            return []
        if s is not None:
            self._end_session(f"replaced by a new session from {conn.peer} after {t - s.last_rx:.2f} s of silence")
        self.pending.pop(conn.sock, None)
        conn.authed, conn.last_seq, conn.last_rx = True, seq, t
        self.session = conn
        self.known_hosts = {self.p.client_host, conn.host}
        self.stats.sessions += 1
        self.log("info", f"PLC session opened by {conn.peer} (mode {protocol.mode_name(self.logic.mode)})")
        self._send(conn, protocol.Ack(seq, protocol.Auth.TYPE, protocol.OK, self.logic.mode))
        return frames[1:]

    def _send(self, conn: _Conn, msg: protocol.Message) -> None:
        conn.out += protocol.encode(msg, conn.seq)
        conn.seq = (conn.seq + 1) & 0xFFFF
        self.frames_sent += 1

    def _flush(self, conn: _Conn) -> None:
        if not conn.out:
            return
        try:
            n = conn.sock.send(conn.out)
            del conn.out[:n]
        except BlockingIOError:
            pass
        except OSError as exc:
            if conn is self.session:
                self._end_session(str(exc))
            else:
                self._close(conn)
            return
        if len(conn.out) > 1 << 20:
            if conn is self.session:
                self._end_session("the client does not read (1 MiB of frames queued)")
            else:
                self._close(conn)

    def send_state(self, state: protocol.State) -> None:
        if self.session is not None:
            conn = self.session
            self._send(conn, state)
            self.states_sent += 1
            self._flush(conn)

    def close(self) -> None:
        if self.session is not None:
            self._end_session("PLC shutting down")
        for conn in list(self.pending.values()):
            self._close(conn)
        if self.listening:
            self.sel.unregister(self.listener)
        self.listener.close()
        self.sel.unregister(self._wake_r)
        self._wake_r.close()
        self._wake_w.close()
        self.sel.close()


_WAKE = object()  # the selector key's data of the wake-up socket


def listening_exposure(address: str) -> str:
    """Why a listening address reaches beyond this machine ("" for a loopback one)."""
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return f"{address} is not a numeric address"
    if ip.is_loopback:
        return ""
    if ip.is_unspecified:
        return "every network interface of this machine"
    return "a network interface, not loopback"


def is_address_in_use(exc: OSError) -> bool:
    return exc.errno == errno.EADDRINUSE
