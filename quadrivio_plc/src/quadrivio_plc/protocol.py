"""Quadrivio PLC wire protocol: one codec for the PLCClient and the emulated PLC.

See ``PROTOCOL.md`` for the full description. A frame (little-endian)::

    offset  size  field
    0       2     magic  b"QV"
    2       1     version (3)
    3       1     message type
    4       2     sequence number (per sender, wraps at 65536)
    6       2     payload length N (at most MAX_PAYLOAD)
    8       N     payload
    8+N     2     CRC-16/CCITT-FALSE of bytes 0 .. 8+N-1 (poly 0x1021, init 0xFFFF)

:class:`FrameDecoder` is a streaming decoder: it is fed arbitrary chunks of bytes and
returns the valid frames; anything else (garbage, truncated or oversized frames, bad
checksums, unknown types, wrong payload sizes) is counted per reason, reported, and
skipped by resynchronising on the next magic. It never raises on input.

Sessions (version 2): the PLC opens every connection with HELLO (a random nonce); the
client answers AUTH, an HMAC-SHA256 of the nonce under a shared key read from a file
(:func:`load_key`). Only then does the PLC act on the connection's frames, and only on
frames whose sequence number advances (:func:`seq_advanced`). Version 3 adds RESET, the
acknowledgement of a stop for a fault, and the re-entry rules it serves (PROTOCOL.md).
"""

from __future__ import annotations

import binascii
import hashlib
import hmac
import math
import os
import secrets
import struct
from dataclasses import dataclass, field
from typing import Dict, List, Optional, Tuple, Union

MAGIC = b"QV"
VERSION = 3  # 2: authenticated sessions (HELLO / AUTH), sequence numbers that must advance; 3: RESET,
#              re-entry at a verified standstill only, latched faults acknowledged
HEADER = struct.Struct("<2sBBHH")  # magic, version, type, seq, payload length
CRC = struct.Struct("<H")
MAX_PAYLOAD = 128
MAX_FRAME = 8 + MAX_PAYLOAD + 2
NONCE_SIZE = 16
MAC_SIZE = 32  # HMAC-SHA256
DEFAULT_PORT = 5020

# Operating modes (match quadrivio_plc/VehicleState MODE_*)
MODE_HALT, MODE_SAFE, MODE_MANUAL, MODE_ASSISTED, MODE_AUTO = 0, 1, 2, 3, 4
MODE_NAMES = {MODE_HALT: "HALT", MODE_SAFE: "SAFE", MODE_MANUAL: "MANUAL", MODE_ASSISTED: "ASSISTED",
              MODE_AUTO: "AUTO"}
MODE_BY_NAME = {v: k for k, v in MODE_NAMES.items()}

# Setpoint sources
SOURCE_MANUAL, SOURCE_AUTO = 1, 2
SOURCE_NAMES = {SOURCE_MANUAL: "manual", SOURCE_AUTO: "auto"}

# Fault flags (match quadrivio_plc/VehicleState FAULT_*)
FAULT_WATCHDOG, FAULT_ESTOP, FAULT_SETPOINT_CLAMPED, FAULT_LINK = 1, 2, 4, 8

# Status / reason codes of ACK and REFUSED frames
OK, BAD_TRANSITION, WRONG_SOURCE, NOT_ACCEPTING, CLAMPED, BUSY, BAD_VALUE = 0, 1, 2, 3, 4, 5, 6
NOT_AUTHENTICATED, STALE, NOT_ACKNOWLEDGED, NOT_AT_STANDSTILL = 7, 8, 9, 10
FAULT_NAMES = {FAULT_WATCHDOG: "WATCHDOG", FAULT_ESTOP: "ESTOP", FAULT_SETPOINT_CLAMPED: "SETPOINT_CLAMPED",
               FAULT_LINK: "LINK"}
STATUS_NAMES = {OK: "ok", BAD_TRANSITION: "mode transition not allowed",
                WRONG_SOURCE: "setpoint source does not match the mode",
                NOT_ACCEPTING: "mode does not accept setpoints", CLAMPED: "setpoint clamped to the limits",
                BUSY: "another client session is active", BAD_VALUE: "value is not a finite number",
                NOT_AUTHENTICATED: "not authenticated (wrong key, or a frame before AUTH)",
                STALE: "sequence number did not advance (replayed or out-of-order frame)",
                NOT_ACKNOWLEDGED: "a WATCHDOG or LINK fault is not acknowledged (RESET first)",
                NOT_AT_STANDSTILL: "the vehicle is not at a verified standstill"}


def fault_names(faults: int) -> str:
    """'WATCHDOG+LINK' for a fault mask ('none' for 0)."""
    return "+".join(name for bit, name in FAULT_NAMES.items() if faults & bit) or "none"


@dataclass(frozen=True)
class Setpoint:
    """Client -> PLC, type 0x01: a setpoint from one source."""
    TYPE = 0x01
    FMT = struct.Struct("<Bfff")
    source: int  # SOURCE_*
    speed: float  # [m/s]
    handlebar: float  # [rad]
    brake: float  # [1]

    def pack(self) -> bytes:
        return self.FMT.pack(self.source, self.speed, self.handlebar, self.brake)


@dataclass(frozen=True)
class ModeRequest:
    """Client -> PLC, type 0x02: request an operating mode."""
    TYPE = 0x02
    FMT = struct.Struct("<B")
    mode: int

    def pack(self) -> bytes:
        return self.FMT.pack(self.mode)


@dataclass(frozen=True)
class Heartbeat:
    """Client -> PLC, type 0x03: keeps the session alive when there is nothing else to send (SAFE,
    HALT). It never feeds the watchdog: only fresh setpoints of the mode's source do (PROTOCOL.md)."""
    TYPE = 0x03
    FMT = struct.Struct("<")

    def pack(self) -> bytes:
        return b""


@dataclass(frozen=True)
class Auth:
    """Client -> PLC, type 0x04: the answer to HELLO, HMAC-SHA256(key, AUTH_LABEL + nonce)."""
    TYPE = 0x04
    FMT = struct.Struct(f"<{MAC_SIZE}s")
    mac: bytes

    def pack(self) -> bytes:
        return self.FMT.pack(self.mac)


@dataclass(frozen=True)
class Reset:
    """Client -> PLC, type 0x05: acknowledge the latched faults in ``faults`` (WATCHDOG, LINK);
    accepted at a verified standstill only (PROTOCOL.md, Re-entry)."""
    TYPE = 0x05
    FMT = struct.Struct("<H")
    faults: int

    def pack(self) -> bytes:
        return self.FMT.pack(self.faults)


@dataclass(frozen=True)
class Hello:
    """PLC -> client, type 0x84: first frame of every connection, the challenge to answer."""
    TYPE = 0x84
    FMT = struct.Struct(f"<{NONCE_SIZE}sff")
    nonce: bytes
    watchdog: float  # [s] PLC time without a fresh setpoint before it brakes
    session_timeout: float  # [s] PLC time without any valid frame before it ends the session

    def pack(self) -> bytes:
        return self.FMT.pack(self.nonce, self.watchdog, self.session_timeout)


@dataclass(frozen=True)
class State:
    """PLC -> client, type 0x81: the vehicle state, at the PLC state rate."""
    TYPE = 0x81
    FMT = struct.Struct("<dBHHffffff")
    plc_time: float  # [s]
    mode: int
    faults: int
    ack_seq: int  # sequence number of the last valid frame received from the client
    wheel_speed: float  # [m/s]
    handlebar: float  # [rad]
    throttle: float  # [1]
    brake: float  # [1]
    setpoint_speed: float  # [m/s]
    setpoint_handlebar: float  # [rad]

    def pack(self) -> bytes:
        return self.FMT.pack(self.plc_time, self.mode, self.faults, self.ack_seq, self.wheel_speed,
                             self.handlebar, self.throttle, self.brake, self.setpoint_speed,
                             self.setpoint_handlebar)


@dataclass(frozen=True)
class Ack:
    """PLC -> client, type 0x82: immediate answer to every valid client frame."""
    TYPE = 0x82
    FMT = struct.Struct("<HBBB")
    ack_seq: int  # sequence number of the frame answered
    acked_type: int  # its message type
    status: int  # OK or a reason code
    mode: int  # the PLC mode after handling it

    def pack(self) -> bytes:
        return self.FMT.pack(self.ack_seq, self.acked_type, self.status, self.mode)


@dataclass(frozen=True)
class Refused:
    """PLC -> client, type 0x83: the connection is refused (sent before closing it)."""
    TYPE = 0x83
    reason: int
    text: str

    def pack(self) -> bytes:
        return struct.pack("<B", self.reason) + self.text.encode("utf-8")[:MAX_PAYLOAD - 1]


Message = Union[Setpoint, ModeRequest, Heartbeat, Auth, Reset, State, Ack, Refused, Hello]
_FIXED = {cls.TYPE: cls for cls in (Setpoint, ModeRequest, Heartbeat, Auth, Reset, State, Ack, Hello)}


def crc16(data: bytes) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection); check('123456789') = 0x29B1."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode(msg: Message, seq: int) -> bytes:
    """One complete frame carrying ``msg`` with sequence number ``seq``."""
    payload = msg.pack()
    head = HEADER.pack(MAGIC, VERSION, msg.TYPE, seq & 0xFFFF, len(payload))
    body = head + payload
    return body + CRC.pack(crc16(body))


def _decode_payload(mtype: int, payload: bytes) -> Message:
    if mtype == Refused.TYPE:
        if not payload:
            raise ValueError("empty REFUSED payload")
        return Refused(payload[0], payload[1:].decode("utf-8", errors="replace"))
    cls = _FIXED.get(mtype)
    if cls is None:
        raise KeyError(mtype)
    if len(payload) != cls.FMT.size:
        raise ValueError(f"payload of {len(payload)} bytes, {cls.__name__} has {cls.FMT.size}")
    return cls(*cls.FMT.unpack(payload))


@dataclass
class DecodeStats:
    frames: int = 0
    bytes_skipped: int = 0
    errors: Dict[str, int] = field(default_factory=dict)

    @property
    def bad_frames(self) -> int:
        return sum(self.errors.values())


class FrameDecoder:
    """Streaming frame decoder with resynchronisation (see module docstring).

    ``feed(chunk)`` returns ``[(seq, message), ...]``; rejected input is counted in
    ``stats.errors`` by reason, and ``pop_problems()`` summarises the rejections since
    the last call, one line per reason (for rate-limited logging).

    The cost is bounded per byte whatever arrives: the buffer is scanned with an index
    (no copy per rejected byte), a rejection is a counter increment, and at most one
    incomplete frame (< ``MAX_FRAME`` bytes) is kept between calls.
    """

    REASONS = ("garbage", "bad version", "oversized", "bad checksum", "unknown type", "bad payload")

    def __init__(self) -> None:
        self.buf = bytearray()
        self.stats = DecodeStats()
        self._since: Dict[str, int] = {}
        self._first: Dict[str, str] = {}

    def _reject(self, reason: str, detail: str, skip: int) -> None:
        self.stats.errors[reason] = self.stats.errors.get(reason, 0) + 1
        self.stats.bytes_skipped += skip
        if reason not in self._since:
            self._first[reason] = detail
        self._since[reason] = self._since.get(reason, 0) + 1

    def pop_problems(self) -> List[str]:
        """One line per reason rejected since the last call: count and the first example."""
        out = [f"{n} x {reason} (first: {self._first[reason]})" if n > 1 else f"{reason}: {self._first[reason]}"
               for reason, n in self._since.items()]
        self._since, self._first = {}, {}
        return out

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame (always < MAX_FRAME)."""
        return len(self.buf)

    def feed(self, chunk: bytes) -> List[Tuple[int, Message]]:
        buf = self.buf
        buf.extend(chunk)
        out: List[Tuple[int, Message]] = []
        pos, n = 0, len(buf)
        while True:
            start = buf.find(MAGIC, pos)
            if start < 0:
                # Keep a possible first magic byte at the end; drop the rest.
                keep = 1 if n > pos and buf[-1:] == MAGIC[:1] else 0
                if n - keep > pos:
                    self._reject("garbage", f"{n - keep - pos} bytes without a frame start", n - keep - pos)
                pos = n - keep
                break
            if start > pos:
                self._reject("garbage", f"{start - pos} bytes before a frame start", start - pos)
                pos = start
            if n - pos < HEADER.size:
                break
            _, version, mtype, seq, length = HEADER.unpack_from(buf, pos)
            if version != VERSION:
                self._reject("bad version", f"version {version}, expected {VERSION}", 1)
                pos += 1
                continue
            if length > MAX_PAYLOAD:
                self._reject("oversized", f"payload length {length} > {MAX_PAYLOAD}", 1)
                pos += 1
                continue
            total = HEADER.size + length + CRC.size
            if n - pos < total:
                break
            body = bytes(buf[pos:pos + HEADER.size + length])
            (crc,) = CRC.unpack_from(buf, pos + HEADER.size + length)
            if crc != crc16(body):
                self._reject("bad checksum", f"type 0x{mtype:02x} seq {seq}", 1)
                pos += 1
                continue
            try:
                msg = _decode_payload(mtype, body[HEADER.size:])
            except KeyError:
                self._reject("unknown type", f"type 0x{mtype:02x} seq {seq}", total)
                pos += total
                continue
            except (ValueError, struct.error) as exc:
                self._reject("bad payload", f"type 0x{mtype:02x} seq {seq}: {exc}", total)
                pos += total
                continue
            pos += total
            self.stats.frames += 1
            out.append((seq, msg))
        del buf[:pos]
        return out


# ------------------------------------------------------------------ session keys
AUTH_LABEL = b"quadrivio-plc-auth-v2"
MIN_KEY_CHARS = 16


class KeyFileError(ValueError):
    """The shared key file is missing, unreadable or too short (the message names it)."""


def default_key_file() -> str:
    """``$ROS_HOME/quadrivio_plc.key`` (``~/.ros`` without ROS_HOME): the key both ends read."""
    home = os.environ.get("ROS_HOME") or os.path.join(os.path.expanduser("~"), ".ros")
    return os.path.join(home, "quadrivio_plc.key")


MIN_KEY_DISTINCT = 8  # a key of fewer distinct characters is trivially guessed ("aaaa...", "abab...")


def load_key(path: str) -> bytes:
    """The shared key: the file's text, surrounding whitespace removed, at least 16 characters."""
    path = path or default_key_file()
    if os.path.isdir(path):
        raise KeyFileError(f"PLC key file {path} is a directory, not a key file")
    try:
        with open(path, "rb") as fh:
            key = fh.read(4096).strip()
    except FileNotFoundError:
        raise KeyFileError(f"PLC key file {path} does not exist (the emulated PLC creates it; for the "
                           f"vehicle, copy the PLC's key there)") from None
    except OSError as exc:
        raise KeyFileError(f"PLC key file {path} cannot be read: {exc.strerror or exc}") from None
    if len(key) < MIN_KEY_CHARS:
        what = "only whitespace" if key == b"" and os.path.getsize(path) else f"{len(key)} characters"
        raise KeyFileError(f"PLC key file {path} holds {what}; a key needs at least {MIN_KEY_CHARS} characters")
    return key


def key_warnings(path: str, key: bytes) -> List[str]:
    """What is wrong with a usable key file, each in one line naming it: readable by other users,
    or a key made of a few repeated characters (both ends call this and log a warning)."""
    path = path or default_key_file()
    out = []
    try:
        mode = os.stat(path).st_mode & 0o777
    except OSError:
        mode = 0
    if mode & 0o077:
        out.append(f"PLC key file {path} is readable by other users (mode {mode:04o}): anyone on this machine "
                   f"can drive the vehicle; chmod 600 {path}")
    if len(set(key)) < MIN_KEY_DISTINCT:
        out.append(f"PLC key file {path} holds a weak key ({len(set(key))} distinct characters in {len(key)}): "
                   f"replace it with a random one, e.g. `openssl rand -hex 32 > {path}`")
    return out


def ensure_key(path: str) -> bytes:
    """The key in ``path``; a new random one (mode 0600, written atomically) if there is no file."""
    path = path or default_key_file()
    if not os.path.exists(path):
        os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
        tmp = f"{path}.{os.getpid()}.tmp"
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as fh:
            fh.write(secrets.token_hex(32) + "\n")
        try:
            os.link(tmp, path)  # fails if another process made one meanwhile: keep theirs
        except FileExistsError:
            pass
        finally:
            os.unlink(tmp)
    return load_key(path)


def new_nonce() -> bytes:
    return secrets.token_bytes(NONCE_SIZE)


def auth_mac(key: bytes, nonce: bytes) -> bytes:
    return hmac.new(key, AUTH_LABEL + nonce, hashlib.sha256).digest()


def auth_ok(key: bytes, nonce: bytes, mac: bytes) -> bool:
    return hmac.compare_digest(auth_mac(key, nonce), mac)


def seq_advanced(seq: int, last: Optional[int]) -> bool:
    """Whether ``seq`` is after ``last`` (mod 65536, within half the range)."""
    return last is None or 0 < ((seq - last) & 0xFFFF) < 0x8000


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def mode_name(mode: int) -> str:
    return MODE_NAMES.get(mode, f"unknown({mode})")


def parse_mode(text: Union[str, int]) -> Optional[int]:
    """A mode from its name (case-insensitive) or number; None when unknown."""
    if isinstance(text, int):
        return text if text in MODE_NAMES else None
    t = str(text).strip().upper()
    if t.isdigit():
        return int(t) if int(t) in MODE_NAMES else None
    return MODE_BY_NAME.get(t)
