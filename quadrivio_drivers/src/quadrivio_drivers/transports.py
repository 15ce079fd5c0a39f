"""Line transports for NMEA: a serial port (or pseudo-terminal) and a TCP client.

Each yields decoded text lines and raises ``OSError`` with a message naming the
device when it cannot open or loses it; the caller reconnects.
"""

from __future__ import annotations

import socket
from typing import Iterator


def serial_lines(device: str, baud: int, timeout: float = 0.5) -> Iterator[str]:
    import serial

    try:
        port = serial.Serial(device, baud, timeout=timeout)
    except (serial.SerialException, ValueError) as exc:
        raise OSError(f"cannot open serial device {device}: {exc}") from exc
    buf = b""
    try:
        while True:
            try:
                # Whatever is waiting, or block (up to the timeout) for the first byte: a
                # fixed-size read would hold a sentence until the next epoch fills it.
                chunk = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise OSError(f"serial device {device}: {exc}") from exc
            if not chunk:
                yield ""  # idle: lets the caller check for shutdown
                continue
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for raw in lines:
                yield raw.decode("ascii", errors="replace")
    finally:
        port.close()


def tcp_lines(host: str, port: int, timeout: float = 0.5) -> Iterator[str]:
    try:
        sock = socket.create_connection((host, port), timeout=2.0)
    except OSError as exc:
        raise OSError(f"cannot connect to the GPS at {host}:{port}: {exc.strerror or exc}") from exc
    sock.settimeout(timeout)
    buf = b""
    try:
        while True:
            try:
                chunk = sock.recv(4096)
            except socket.timeout:
                yield ""
                continue
            if not chunk:
                raise OSError(f"the GPS at {host}:{port} closed the connection")
            buf += chunk
            *lines, buf = buf.split(b"\n")
            for raw in lines:
                yield raw.decode("ascii", errors="replace")
    finally:
        sock.close()
