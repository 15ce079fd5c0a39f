"""The roscpp guard's core (``guard_core.h``) in this process, through ctypes: what the
guard node runs, with :class:`.guard.Guard`'s interface, for the closed loop in one process
(:mod:`quadrivio.closed_loop`). The Python guard stays the reference: ``guard_core.h`` is
cross-tested against it (``test/test_guard_native.py``), and this wrapper against both
(``test/test_guard_native.py::test_the_wrapper_decides_as_the_python_guard``).

The library is ``libquadrivio_guard.so`` of the built workspace (``make setup``); the
configuration goes over as :mod:`.ros.guard_config` writes it for the node."""

from __future__ import annotations

import ctypes
import io
import threading
from typing import Dict, Optional, Tuple

import numpy as np

from .fields import ScanPoints
from .guard import Decision, GuardNodeParams, GuardParams, Setpoint
from .native import find_library

_LIB = None
_LIB_LOCK = threading.Lock()
_NUMBERS = 15  # qv_guard_decide's numbers
_TEXTS = 2048  # [bytes] its reason, field and scanner


class GuardUnavailable(RuntimeError):
    """libquadrivio_guard.so was not found or does not load (the workspace is not built)."""


def load_library():
    """The C core (loaded once)."""
    global _LIB
    with _LIB_LOCK:
        if _LIB is not None:
            return _LIB
        try:
            lib = ctypes.CDLL(find_library("libquadrivio_guard.so"))
        except (FileNotFoundError, OSError) as exc:
            raise GuardUnavailable(f"the native guard: {exc} (build the workspace: make setup)") from None
        d, p, sz = ctypes.c_double, ctypes.POINTER(ctypes.c_double), ctypes.c_size_t
        lib.qv_guard_create.restype = ctypes.c_void_p
        lib.qv_guard_create.argtypes = [ctypes.c_char_p, sz, ctypes.c_char_p, sz]
        lib.qv_guard_destroy.argtypes = [ctypes.c_void_p]
        lib.qv_guard_on_state.argtypes = [ctypes.c_void_p, d, d, d]
        lib.qv_guard_on_pitch.argtypes = [ctypes.c_void_p, d, d]
        lib.qv_guard_on_pose.argtypes = [ctypes.c_void_p, d, d, d, d, d]
        lib.qv_guard_on_scan.argtypes = [ctypes.c_void_p, sz, d, p, sz, ctypes.c_int, ctypes.c_int, ctypes.c_int,
                                         ctypes.c_int, p, p, ctypes.c_char_p]
        lib.qv_guard_decide.argtypes = [ctypes.c_void_p, d, d, d, p, ctypes.c_char_p, sz]
        lib.qv_guard_command.argtypes = [ctypes.c_void_p, ctypes.c_int, d, d, d, d, p]
        lib.qv_guard_state.restype = ctypes.c_int
        lib.qv_guard_state.argtypes = [ctypes.c_void_p, p]
        lib.qv_guard_defaults.restype = sz
        lib.qv_guard_defaults.argtypes = [ctypes.c_char_p, sz]
        _LIB = lib
        return lib


def native_defaults() -> Dict[str, float]:
    """The C++ core's own defaults of the configuration's numeric keys (guard.yaml's names; the
    node's keys as ``node_<name>``). The nodes always pass every key, so these matter only where
    the core is used without a configuration; a test holds them to :class:`GuardParams`."""
    lib = load_library()
    n = lib.qv_guard_defaults(None, 0)
    buf = ctypes.create_string_buffer(n)
    lib.qv_guard_defaults(buf, n)
    return {k: float(v) for k, v in (line.split() for line in buf.value.decode().splitlines())}


class NativeGuard:
    """:class:`.guard.Guard`'s inputs, ``decide``, ``command``, ``state`` and stop counters,
    computed by ``guard_core.h``. ``hf``: the DEM (a :class:`Heightfield`) if the guard knows
    the terrain (the braking slope), else None."""

    def __init__(self, p: GuardParams, vehicle, hf=None, node: Optional[GuardNodeParams] = None) -> None:
        from .ros.guard_config import emit

        self._lib = load_library()
        self.p = p
        self._index = {s.topic: i for i, s in enumerate(p.scanners)}
        out = io.BytesIO()
        emit(out, p, node or GuardNodeParams(), vehicle, hf)
        text = out.getvalue()
        error = ctypes.create_string_buffer(512)
        handle = self._lib.qv_guard_create(text, len(text), error, len(error))
        if not handle:
            raise ValueError(f"the native guard refused its configuration: {error.value.decode()}")
        self._h = ctypes.c_void_p(handle)
        self._numbers = (ctypes.c_double * _NUMBERS)()
        self._texts = ctypes.create_string_buffer(_TEXTS)
        self._three = (ctypes.c_double * 3)()
        self.protective_stops = self.fault_stops = self.zone_stops = 0

    def __del__(self) -> None:
        h = getattr(self, "_h", None)
        if h is not None and h.value:
            self._lib.qv_guard_destroy(h)
            self._h = None

    # ---------------------------------------------------------------- inputs
    def on_state(self, stamp: float, speed: float, handlebar: float) -> None:
        self._lib.qv_guard_on_state(self._h, stamp, speed, handlebar)

    def on_pitch(self, stamp: float, pitch: float) -> None:
        self._lib.qv_guard_on_pitch(self._h, stamp, pitch)

    def on_pose(self, stamp: float, x: float, y: float, yaw: float, sd: float) -> None:
        self._lib.qv_guard_on_pose(self._h, stamp, x, y, yaw, sd)

    def on_scan(self, topic: str, stamp: float, points: Optional[ScanPoints], error: str = "") -> None:
        i = self._index[topic]  # a KeyError for a topic that is no scanner's, as the Python guard's
        if points is None:
            self._lib.qv_guard_on_scan(self._h, i, stamp, None, 0, 0, 0, 0, 0, None, None, error.encode())
            return
        dp = ctypes.POINTER(ctypes.c_double)
        xy = np.ascontiguousarray(points.xy, dtype=np.float64).reshape(-1, 2)
        geometry = free = None
        rays = points.rays
        if rays is not None:
            if len(rays.free) != points.n_rays:
                raise ValueError(f"{len(rays.free)} rays' free ranges for a scan of {points.n_rays} rays")
            geometry = np.array(rays.origin + tuple(rays.m) + (rays.angle_min, rays.increment), dtype=np.float64)
            free = np.ascontiguousarray(rays.free, dtype=np.float64)
        self._lib.qv_guard_on_scan(self._h, i, stamp, xy.ctypes.data_as(dp), len(xy), int(points.n_rays),
                                   int(points.n_invalid), int(points.n_zero), int(points.n_beyond),
                                   None if geometry is None else geometry.ctypes.data_as(dp),
                                   None if free is None else free.ctypes.data_as(dp), None)

    # ---------------------------------------------------------------- decide
    def decide(self, now: float, req_speed: float, req_handlebar: float) -> Decision:
        n = self._numbers
        self._lib.qv_guard_decide(self._h, now, req_speed, req_handlebar, n, self._texts, _TEXTS)
        reason, field, scanner = self._texts.raw.split(b"\0", 3)[:3]
        self.protective_stops, self.fault_stops, self.zone_stops = int(n[12]), int(n[13]), int(n[14])
        return Decision(action=int(n[0]), limit=n[1], reason=reason.decode(), field=field.decode(), free=n[2],
                        protective=n[3], protective_request=n[4], warning=n[5],
                        nearest=(n[7], n[8]) if n[6] else None, scanner=scanner.decode(), scan_stamp=n[9],
                        direction=int(n[10]), slope=n[11])

    def command(self, d: Decision, req_speed: float, req_handlebar: float, req_brake: float) -> Setpoint:
        s = self._three
        self._lib.qv_guard_command(self._h, d.action, d.limit, req_speed, req_handlebar, req_brake, s)
        return Setpoint(s[0], s[1], s[2])

    @property
    def state(self) -> Optional[Tuple[float, float, float]]:
        """(stamp, speed, handlebar) of the latest vehicle state, None before one."""
        s = self._three
        return (s[0], s[1], s[2]) if self._lib.qv_guard_state(self._h, s) else None


def available() -> bool:
    try:
        load_library()
        return True
    except GuardUnavailable:
        return False

