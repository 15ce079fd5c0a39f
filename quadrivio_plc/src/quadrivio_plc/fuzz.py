"""Seeded generators of hostile and broken PLC input, for the fault-injection suite.

:class:`FrameFuzzer` makes byte strings of every kind a confused, broken or hostile
client can send: random bytes, truncated frames, oversized length fields, bad
checksums, wrong versions, unknown types, wrong payload sizes, replayed sequence
numbers, setpoints that are out of mode, from the wrong source, or not finite. Valid
frames that would make the vehicle drive (mode requests to a driving mode) are never
generated, so that a fuzzed PLC must end where it started: braked.
"""

from __future__ import annotations

from collections import Counter
from typing import List, Tuple

import numpy as np

from . import protocol

KINDS = ("random", "truncated", "oversized", "bad checksum", "bad version", "unknown type", "bad payload",
         "replayed", "out of mode", "wrong source", "not finite", "heartbeat", "stop request")


class FrameFuzzer:
    """``chunk()`` returns ``(kind, bytes)``; ``counts`` says how many of each were made."""

    def __init__(self, rng: np.random.Generator, first_seq: int = 1) -> None:
        self.rng = rng
        self.seq = first_seq & 0xFFFF
        self.counts: Counter = Counter()

    def _next_seq(self) -> int:
        s = self.seq
        self.seq = (self.seq + 1) & 0xFFFF
        return s

    def _setpoint(self, source: int, speed: float, handlebar: float, brake: float) -> bytes:
        return protocol.encode(protocol.Setpoint(source, speed, handlebar, brake), self._next_seq())

    def chunk(self) -> Tuple[str, bytes]:
        r = self.rng
        kind = KINDS[int(r.integers(len(KINDS)))]
        self.counts[kind] += 1
        if kind == "random":
            data = r.integers(0, 256, int(r.integers(1, 200)), dtype=np.uint8).tobytes()
        elif kind == "truncated":
            f = self._setpoint(protocol.SOURCE_AUTO, 3.0, 0.3, 0.0)
            data = f[:int(r.integers(1, len(f)))]
        elif kind == "oversized":
            data = protocol.HEADER.pack(protocol.MAGIC, protocol.VERSION, protocol.Setpoint.TYPE, self._next_seq(),
                                 int(r.integers(protocol.MAX_PAYLOAD + 1, 65536))) + bytes(int(r.integers(0, 64)))
        elif kind == "bad checksum":
            f = bytearray(self._setpoint(protocol.SOURCE_AUTO, 3.0, 0.0, 0.0))
            f[-1] ^= 0xFF
            data = bytes(f)
        elif kind == "bad version":
            f = bytearray(protocol.encode(protocol.ModeRequest(protocol.MODE_AUTO), self._next_seq()))
            f[2] = int(r.choice([0, 1, 3, 255]))
            data = bytes(f)
        elif kind == "unknown type":
            body = protocol.HEADER.pack(protocol.MAGIC, protocol.VERSION, int(r.choice([0x00, 0x06, 0x7F, 0x90, 0xFF])),
                                 self._next_seq(), 4) + b"\x01\x02\x03\x04"
            data = body + protocol.CRC.pack(protocol.crc16(body))
        elif kind == "bad payload":
            payload = bytes(int(r.integers(0, 20)))
            if len(payload) == protocol.Setpoint.FMT.size:
                payload += b"\x00"
            body = protocol.HEADER.pack(protocol.MAGIC, protocol.VERSION, protocol.Setpoint.TYPE, self._next_seq(), len(payload)) + payload
            data = body + protocol.CRC.pack(protocol.crc16(body))
        elif kind == "replayed":
            old = (self.seq - int(r.integers(1, 1000))) & 0xFFFF
            data = protocol.encode(protocol.Setpoint(protocol.SOURCE_AUTO, 3.0, 0.0, 0.0), old)
        elif kind == "out of mode":  # setpoints while the PLC is in SAFE: never acted on
            data = self._setpoint(int(r.choice([protocol.SOURCE_AUTO, protocol.SOURCE_MANUAL])), float(r.uniform(-2, 5)),
                                  float(r.uniform(-0.5, 0.5)), 0.0)
        elif kind == "wrong source":
            data = self._setpoint(int(r.choice([0, 3, 255])), 3.0, 0.0, 0.0)
        elif kind == "not finite":
            bad = [float("nan"), float("inf"), float("-inf")]
            data = self._setpoint(protocol.SOURCE_AUTO, bad[int(r.integers(3))], bad[int(r.integers(3))], 0.0)
        elif kind == "heartbeat":
            data = protocol.encode(protocol.Heartbeat(), self._next_seq())
        else:  # "stop request": SAFE, allowed and harmless
            data = protocol.encode(protocol.ModeRequest(protocol.MODE_SAFE), self._next_seq())
        return kind, data

    def frames(self, n: int) -> List[Tuple[str, bytes]]:
        return [self.chunk() for _ in range(n)]

