"""The simulated GPS receiver's wire output: NMEA 0183 GGA, GST and RMC sentences.

Each GPS epoch (a :class:`~quadrivio_sim.noise.GpsReading`) becomes three sentences
in the order a receiver sends them: GGA (position, fix quality, satellites, HDOP,
altitude above mean sea level, geoid separation), GST (standard deviations of the
position error) and RMC (speed and course over ground, date). Latitude and longitude
carry 8 decimals of a minute (0.02 mm). UTC is the site's ``utc_epoch`` plus sim time.

Transports: a pseudo-terminal whose slave end is linked at a path (what a serial GPS
looks like to a driver) and a TCP server (a networked receiver). Both write without
blocking and count what a missing reader makes them drop.
"""

from __future__ import annotations

import datetime as dt
import errno
import math
import os
import selectors
import socket
from typing import List

import pynmea2

from quadrivio_description.geodesy import LocalFrame

from .noise import FIX, GBAS_FIX, NO_FIX, SBAS_FIX, GpsReading

QUALITY = {NO_FIX: 0, FIX: 1, SBAS_FIX: 2, GBAS_FIX: 4}  # NavSatStatus -> GGA quality
KNOT = 1852.0 / 3600.0  # [m/s]


def _degrees_minutes(deg: float, width: int) -> str:
    """``dddmm.mmmmmmmm``: whole degrees, then minutes with 8 decimals (0.02 mm)."""
    a = abs(deg)
    d = int(a)
    m = round((a - d) * 60.0, 8)
    if m >= 60.0:  # rounding carried into the next degree
        d, m = d + 1, m - 60.0
    return f"{d:0{width}d}{m:011.8f}"


def _lat(deg: float):
    return _degrees_minutes(deg, 2), "N" if deg >= 0 else "S"


def _lon(deg: float):
    return _degrees_minutes(deg, 3), "E" if deg >= 0 else "W"


class NmeaEncoder:
    def __init__(self, frame: LocalFrame, utc_epoch: float, geoid_separation: float = 0.0, talker: str = "GP"):
        self.frame = frame
        self.utc_epoch = utc_epoch
        self.geoid_separation = geoid_separation  # [m] ellipsoid height - mean sea level height
        self.talker = talker

    def encode(self, r: GpsReading) -> List[str]:
        when = dt.datetime.fromtimestamp(self.utc_epoch + r.stamp, tz=dt.timezone.utc)
        hms = when.strftime("%H%M%S.") + f"{when.microsecond // 10000:02d}"
        date = when.strftime("%d%m%y")
        t = self.talker
        if r.position is None:
            gga = pynmea2.GGA(t, "GGA", (hms, "", "", "", "", "0", "00", "99.9", "", "M", "", "M", "", ""))
            gst = pynmea2.GST(t, "GST", (hms, "", "", "", "", "", "", ""))
            rmc = pynmea2.RMC(t, "RMC", (hms, "V", "", "", "", "", "", "", date, "", "", "N"))
            return [str(gga), str(gst), str(rmc)]
        lat, lon, alt = self.frame.enu_to_lla(*r.position)
        la, la_h = _lat(lat)
        lo, lo_h = _lon(lon)
        quality = QUALITY[r.status]
        gga = pynmea2.GGA(t, "GGA", (hms, la, la_h, lo, lo_h, str(quality), f"{r.satellites:02d}", f"{r.hdop:.1f}",
                                     f"{alt - self.geoid_separation:.3f}", "M", f"{self.geoid_separation:.3f}", "M",
                                     "", ""))
        se, sn, su = (math.sqrt(v) for v in r.variances)
        sh = math.sqrt(0.5 * (se * se + sn * sn))
        gst = pynmea2.GST(t, "GST", (hms, f"{sh:.3f}", f"{max(se, sn):.3f}", f"{min(se, sn):.3f}", "0.0",
                                     f"{sn:.3f}", f"{se:.3f}", f"{su:.3f}"))
        ve, vn = r.velocity[0], r.velocity[1]
        speed = math.hypot(ve, vn)
        course = math.degrees(math.atan2(ve, vn)) % 360.0
        mode = {FIX: "A", SBAS_FIX: "D", GBAS_FIX: "R"}[r.status]
        rmc = pynmea2.RMC(t, "RMC", (hms, "A", la, la_h, lo, lo_h, f"{speed / KNOT:.3f}", f"{course:.2f}", date,
                                     "", "", mode))
        return [str(gga), str(gst), str(rmc)]


class PtyOutput:
    """A pseudo-terminal; its slave end is symlinked at ``link`` for the driver to open."""

    def __init__(self, link: str) -> None:
        import pty
        import tty

        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.slave_name = os.ttyname(self.slave)
        self.link = link
        os.makedirs(os.path.dirname(os.path.abspath(link)), exist_ok=True)
        if os.path.islink(link) or os.path.exists(link):
            os.remove(link)
        os.symlink(self.slave_name, link)
        self.dropped = 0
        self.address = f"{link} -> {self.slave_name}"

    def write(self, text: str) -> None:
        data = text.encode("ascii")
        try:
            n = os.write(self.master, data)
            if n < len(data):
                self.dropped += 1
        except OSError as exc:
            if exc.errno not in (errno.EAGAIN, errno.EIO):
                raise
            self.dropped += 1  # nobody reading: the line is lost, as on a serial port

    def close(self) -> None:
        for fd in (self.master, self.slave):
            try:
                os.close(fd)
            except OSError:
                pass
        if os.path.islink(self.link):
            os.remove(self.link)


class TcpOutput:
    """A TCP server sending every line to every connected client."""

    def __init__(self, host: str, port: int) -> None:
        self.server = socket.socket()
        self.server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.server.bind((host, port))
        self.server.listen(4)
        self.server.setblocking(False)
        self.sel = selectors.DefaultSelector()
        self.sel.register(self.server, selectors.EVENT_READ)
        self.clients: List[socket.socket] = []
        self.dropped = 0
        self.address = "tcp://%s:%d" % self.server.getsockname()

    def write(self, text: str) -> None:
        for _key, _ in self.sel.select(0):
            try:
                client, _ = self.server.accept()
                client.setblocking(False)
                self.clients.append(client)
            except OSError:
                pass
        data = text.encode("ascii")
        for c in list(self.clients):
            try:
                c.send(data)
            except BlockingIOError:
                self.dropped += 1
            except OSError:
                self.clients.remove(c)
                c.close()

    def close(self) -> None:
        for c in self.clients:
            c.close()
        self.sel.close()
        self.server.close()


def open_output(spec: str):
    """``pty:/path/to/link`` or ``tcp:[host:]port``; empty: None."""
    if not spec:
        return None
    kind, _, rest = spec.partition(":")
    if kind == "pty" and rest:
        return PtyOutput(rest)
    if kind == "tcp" and rest:
        host, _, port = rest.rpartition(":")
        return TcpOutput(host or "127.0.0.1", int(port))
    raise ValueError(f"NMEA output '{spec}' is neither pty:/path nor tcp:[host:]port")

