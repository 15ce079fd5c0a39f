"""A bare PLC protocol client for tests and fault injection: it speaks the wire protocol
frame by frame, with the sequence numbers, keys and timing the caller chooses (the
PLCClient's :class:`~quadrivio_plc.client.PlcLink` never sends a bad frame on purpose).
"""

from __future__ import annotations

import socket
import time
from typing import List, Optional, Tuple

from . import protocol


class RawClient:
    """One TCP connection to a PLC. ``authenticate(key)`` answers its HELLO."""

    def __init__(self, host: str, port: int, timeout: float = 2.0) -> None:
        self.sock = socket.create_connection((host, port), timeout=timeout)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.decoder = protocol.FrameDecoder()
        self.inbox: List[Tuple[int, protocol.Message]] = []
        self.seq = 0
        self.hello: Optional[protocol.Hello] = None
        self.closed = False

    def close(self) -> None:
        self.sock.close()

    def __enter__(self) -> "RawClient":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ---------------------------------------------------------------- receiving
    def _fill(self, timeout: float) -> bool:
        self.sock.settimeout(max(timeout, 1e-3))
        try:
            data = self.sock.recv(65536)
        except socket.timeout:
            return False
        except OSError:
            data = b""
        if not data:
            self.closed = True
            return False
        self.inbox += self.decoder.feed(data)
        return True

    def wait_for(self, kind, timeout: float = 2.0, pred=lambda m: True) -> Optional[protocol.Message]:
        """The first received message of type ``kind`` satisfying ``pred`` (None on timeout or
        once the PLC closed the connection and nothing matching is left)."""
        deadline = time.monotonic() + timeout
        while True:
            for i, (_, msg) in enumerate(self.inbox):
                if isinstance(msg, kind) and pred(msg):
                    del self.inbox[:i + 1]
                    return msg
            del self.inbox[:-1000]
            left = deadline - time.monotonic()
            if left <= 0 or self.closed:
                return None
            self._fill(left)

    # ------------------------------------------------------------------ sending
    def send_raw(self, data: bytes) -> bool:
        try:
            self.sock.sendall(data)
            return True
        except OSError:
            self.closed = True
            return False

    def send(self, msg: protocol.Message, seq: Optional[int] = None) -> int:
        """Send ``msg`` with ``seq`` (default: the next sequence number); returns the seq used."""
        if seq is None:
            seq = self.seq
            self.seq = (self.seq + 1) & 0xFFFF
        self.send_raw(protocol.encode(msg, seq))
        return seq

    def request(self, msg: protocol.Message, seq: Optional[int] = None, timeout: float = 2.0) -> Optional[protocol.Ack]:
        """Send ``msg`` and wait for its ACK."""
        s = self.send(msg, seq)
        return self.wait_for(protocol.Ack, timeout, lambda a: a.ack_seq == s)

    def authenticate(self, key: bytes, timeout: float = 2.0) -> Optional[protocol.Message]:
        """Answer HELLO with ``key``; returns the PLC's answer: its ACK, or REFUSED (None on timeout)."""
        self.hello = self.wait_for(protocol.Hello, timeout)
        if self.hello is None:
            return None
        s = self.send(protocol.Auth(protocol.auth_mac(key, self.hello.nonce)))
        return self.wait_for((protocol.Ack, protocol.Refused), timeout,
                             lambda m: isinstance(m, protocol.Refused) or m.ack_seq == s)
