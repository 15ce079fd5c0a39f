"""The emulated X20 PLC: operating modes, setpoint gating, watchdog, low-level loops,
and its TCP server (paper section 3.3 and Fig. 5).

:class:`PlcLogic` is the PLC program, driven by sim time. It mirrors the real
vehicle's modes::

    HALT --request--> SAFE --request--> MANUAL | ASSISTED | AUTO
    any  --request--> HALT;   MANUAL | ASSISTED | AUTO --request--> SAFE or another of them
    MANUAL | ASSISTED | AUTO --no valid frame for `watchdog` s--> SAFE (+ FAULT_WATCHDOG)

and accepts setpoints only from the source matching the mode: MANUAL takes everything
from the manual source, AUTO from the autonomous one, ASSISTED the handlebar from the
autonomous source and speed and brake from the manual one (a safety driver on the
throttle). SAFE holds the brake; HALT also freezes the handlebar servo.

:class:`PlcServer` is its transport: a non-blocking TCP server (one client at a time; a
second connection gets a REFUSED frame with the reason and is closed) that answers
every valid frame with an ACK at once and sends STATE frames at the state rate. It is
polled from the simulator loop, so frames are handled between physics steps.
"""

from __future__ import annotations

import errno
import math
import selectors
import socket
from dataclasses import dataclass
from typing import Callable, List, Optional, Tuple

from quadrivio_description.config import param
from quadrivio_plc import protocol as P

from .actuators import Actuation, LowLevelControl


@dataclass(frozen=True)
class PlcParams:
    host: str = param("127.0.0.1", doc="address the emulated PLC listens on (loopback by default)")
    port: int = param(P.DEFAULT_PORT, lo=0, hi=65535, doc="TCP port (0: any free port)")
    cycle: float = param(0.01, lo=0.001, hi=0.1, unit="s", doc="PLC cycle of the low-level loops")
    state_rate: float = param(50.0, lo=1.0, hi=1000.0, unit="Hz", doc="rate of STATE frames to the client")
    watchdog: float = param(0.2, lo=0.01, hi=10.0, unit="s", doc="brake when no valid frame arrives for this long")
    initial_mode: str = param("SAFE", choices=("HALT", "SAFE"), doc="mode at power-on")
    hold_brake: float = param(1.0, lo=0.0, hi=1.0, doc="brake applied in SAFE and HALT")


ALLOWED = {
    P.MODE_HALT: {P.MODE_HALT, P.MODE_SAFE},
    P.MODE_SAFE: {P.MODE_HALT, P.MODE_SAFE, P.MODE_MANUAL, P.MODE_ASSISTED, P.MODE_AUTO},
}
DRIVING = (P.MODE_MANUAL, P.MODE_ASSISTED, P.MODE_AUTO)
for _m in DRIVING:
    ALLOWED[_m] = {P.MODE_HALT, P.MODE_SAFE, *DRIVING}


class PlcLogic:
    """The PLC program (see module docstring). Times are PLC clock seconds (sim time)."""

    def __init__(self, params: PlcParams, control: LowLevelControl) -> None:
        self.p = params
        self.control = control
        self.reset(0.0)

    def reset(self, t: float) -> None:
        self.mode = P.MODE_BY_NAME[self.p.initial_mode]
        self.faults = 0
        self.last_rx = -math.inf
        self.last_seq = 0
        self.sp_speed = 0.0
        self.sp_handlebar = 0.0
        self.sp_brake = 0.0
        self.control.reset()
        self.events: List[str] = []

    # -------------------------------------------------------------- frames
    def handle(self, t: float, seq: int, msg: P.Message) -> Optional[P.Ack]:
        """React to one valid client frame; returns the ACK to send (None for none)."""
        self.last_rx = t
        self.last_seq = seq
        if isinstance(msg, P.ModeRequest):
            return P.Ack(seq, msg.TYPE, self.request_mode(msg.mode), self.mode)
        if isinstance(msg, P.Setpoint):
            return P.Ack(seq, msg.TYPE, self.setpoint(msg.source, msg.speed, msg.handlebar, msg.brake), self.mode)
        if isinstance(msg, P.Heartbeat):
            return P.Ack(seq, msg.TYPE, P.OK, self.mode)
        return None  # PLC-to-client messages coming back: ignored

    def request_mode(self, mode: int) -> int:
        if mode not in P.MODE_NAMES or mode not in ALLOWED[self.mode]:
            self.events.append(f"refused mode change {P.mode_name(self.mode)} -> {P.mode_name(mode)}")
            return P.BAD_TRANSITION
        if mode != self.mode:
            self.events.append(f"mode {P.mode_name(self.mode)} -> {P.mode_name(mode)}")
            if mode in DRIVING and self.mode not in DRIVING:
                # Start from standstill with the handlebar where it is.
                self.sp_speed, self.sp_brake = 0.0, 0.0
                self.sp_handlebar = self.control.handlebar.angle
            self.mode = mode
        if mode in DRIVING:
            self.faults &= ~P.FAULT_WATCHDOG
        self.faults = (self.faults | P.FAULT_ESTOP) if mode == P.MODE_HALT else (self.faults & ~P.FAULT_ESTOP)
        return P.OK

    def setpoint(self, source: int, speed: float, handlebar: float, brake: float) -> int:
        if not P.finite(speed, handlebar, brake):
            return P.BAD_VALUE
        if self.mode not in DRIVING:
            return P.NOT_ACCEPTING
        takes_motion = (self.mode == P.MODE_MANUAL and source == P.SOURCE_MANUAL) or \
                       (self.mode == P.MODE_AUTO and source == P.SOURCE_AUTO) or \
                       (self.mode == P.MODE_ASSISTED and source == P.SOURCE_MANUAL)
        takes_handlebar = (self.mode == P.MODE_MANUAL and source == P.SOURCE_MANUAL) or \
                          (self.mode in (P.MODE_AUTO, P.MODE_ASSISTED) and source == P.SOURCE_AUTO)
        if not (takes_motion or takes_handlebar):
            return P.WRONG_SOURCE
        c_speed, c_handlebar, c_brake, clamped = self.control.clamp(speed, handlebar, brake)
        if takes_motion:
            self.sp_speed, self.sp_brake = c_speed, c_brake
        if takes_handlebar:
            self.sp_handlebar = c_handlebar
        if clamped:
            self.faults |= P.FAULT_SETPOINT_CLAMPED
            self.events.append(f"setpoint clamped: speed {speed:.3f} -> {c_speed:.3f} m/s, handlebar "
                               f"{handlebar:.3f} -> {c_handlebar:.3f} rad, brake {brake:.3f} -> {c_brake:.3f}")
            return P.CLAMPED
        self.faults &= ~P.FAULT_SETPOINT_CLAMPED
        return P.OK

    def force_auto(self, t: float) -> None:
        """Debug path: enter AUTO from any mode (simulation test hook, never on the real PLC)."""
        if self.mode != P.MODE_AUTO:
            self.events.append(f"debug setpoint: mode {P.mode_name(self.mode)} -> AUTO")
            if self.mode not in DRIVING:
                self.sp_handlebar = self.control.handlebar.angle
            self.mode = P.MODE_AUTO
            self.faults &= ~(P.FAULT_WATCHDOG | P.FAULT_ESTOP)
        self.last_rx = t

    # --------------------------------------------------------------- cycle
    def cycle(self, t: float, wheel_speed: float, wheel_rate: float) -> Actuation:
        """One PLC cycle at time ``t``: watchdog, then the low-level loops."""
        if self.mode in DRIVING and t - self.last_rx > self.p.watchdog:
            self.events.append(f"watchdog: no valid frame for {t - self.last_rx:.3f} s > {self.p.watchdog} s, "
                               f"braking ({P.mode_name(self.mode)} -> SAFE)")
            self.mode = P.MODE_SAFE
            self.faults |= P.FAULT_WATCHDOG
        if self.mode in DRIVING:
            return self.control.step(self.sp_speed, self.sp_handlebar, self.sp_brake, wheel_speed, wheel_rate)
        handlebar = None if self.mode == P.MODE_HALT else self.control.handlebar.angle
        return self.control.step(0.0, handlebar, self.p.hold_brake, wheel_speed, wheel_rate)

    def state(self, t: float, wheel_speed: float) -> P.State:
        out = self.control.out
        return P.State(t, self.mode, self.faults, self.last_seq, wheel_speed, out.handlebar, out.throttle,
                       out.brake, self.sp_speed, self.sp_handlebar)

    def pop_events(self) -> List[str]:
        ev, self.events = self.events, []
        return ev


class PlcServer:
    """Non-blocking TCP transport of :class:`PlcLogic` (see module docstring).

    ``clock`` returns the PLC time (sim time) at which incoming frames are handled.
    ``log(level, text)`` receives connection events and rejected input.
    """

    def __init__(self, logic: PlcLogic, host: str, port: int, clock: Callable[[], float],
                 log: Callable[[str, str], None]) -> None:
        self.logic = logic
        self.clock = clock
        self.log = log
        self.sel = selectors.DefaultSelector()
        self.listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self.listener.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.listener.bind((host, port))
        except OSError as exc:
            self.listener.close()
            raise OSError(exc.errno, f"emulated PLC cannot listen on {host}:{port}: {exc.strerror}") from exc
        self.listener.listen(4)
        self.listener.setblocking(False)
        self.address: Tuple[str, int] = self.listener.getsockname()
        self.sel.register(self.listener, selectors.EVENT_READ, "listen")
        self.client: Optional[socket.socket] = None
        self.peer = ""
        self.decoder = P.FrameDecoder()
        self.out = bytearray()
        self.seq = 0
        self.frames_sent = 0
        self.refused = 0
        self.disconnects = 0

    @property
    def connected(self) -> bool:
        return self.client is not None

    def poll(self, timeout: float = 0.0) -> None:
        """Handle pending connections and frames, waiting at most ``timeout`` wall seconds."""
        for key, _ in self.sel.select(timeout=max(0.0, timeout)):
            if key.data == "listen":
                self._accept()
            else:
                self._read()

    def _accept(self) -> None:
        try:
            sock, addr = self.listener.accept()
        except OSError:
            return
        peer = f"{addr[0]}:{addr[1]}"
        if self.client is not None:
            self.refused += 1
            self.log("warn", f"refused PLC connection from {peer}: a client ({self.peer}) is already connected")
            try:
                sock.sendall(P.encode(P.Refused(P.BUSY, f"another client is connected ({self.peer})"), 0))
            except OSError:
                pass
            sock.close()
            return
        sock.setblocking(False)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.client, self.peer = sock, peer
        self.decoder = P.FrameDecoder()
        self.out.clear()
        self.sel.register(sock, selectors.EVENT_READ, "client")
        self.log("info", f"PLC client connected from {peer}")

    def _drop(self, why: str) -> None:
        if self.client is None:
            return
        self.log("warn", f"PLC client {self.peer} disconnected: {why}")
        self.sel.unregister(self.client)
        self.client.close()
        self.client = None
        self.disconnects += 1

    def _read(self) -> None:
        assert self.client is not None
        try:
            data = self.client.recv(65536)
        except BlockingIOError:
            return
        except OSError as exc:
            self._drop(str(exc))
            return
        if not data:
            self._drop("connection closed")
            return
        t = self.clock()
        for seq, msg in self.decoder.feed(data):
            ack = self.logic.handle(t, seq, msg)
            if ack is not None:
                self._send(ack)
        for problem in self.decoder.pop_problems():
            self.log("warn", f"PLC frame from {self.peer} rejected ({problem}); skipped")
        self._flush()

    def _send(self, msg: P.Message) -> None:
        self.out += P.encode(msg, self.seq)
        self.seq = (self.seq + 1) & 0xFFFF
        self.frames_sent += 1

    def _flush(self) -> None:
        if self.client is None or not self.out:
            return
        try:
            n = self.client.send(self.out)
            del self.out[:n]
        except BlockingIOError:
            pass
        except OSError as exc:
            self._drop(str(exc))
            return
        if len(self.out) > 1 << 20:
            self._drop("client does not read (1 MiB of frames queued)")

    def send_state(self, state: P.State) -> None:
        if self.client is not None:
            self._send(state)
            self._flush()

    def close(self) -> None:
        if self.client is not None:
            self._drop("PLC shutting down")
        self.sel.unregister(self.listener)
        self.listener.close()
        self.sel.close()


def is_address_in_use(exc: OSError) -> bool:
    return exc.errno == errno.EADDRINUSE
