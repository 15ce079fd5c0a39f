"""An excitation program for actuator calibration: steps and a sweep of the handlebar at
a steady speed, then steps of the speed, sent open loop as autonomous setpoints.

``rosrun quadrivio_sim calibrate`` identifies the PLC's handlebar and speed loops from
a recording of setpoints and measured responses (the paper's section 3.2 and Fig. 4).
It needs steps large and long enough to show dead time, rate limit and settling, in
both directions, and a speed that goes up and down. This module builds such a
program from a few parameters (a scenario's ``excitation:`` section); the
``excitation`` node plays it on ``/vehicle/setpoint/auto``, on the simulator or on the
vehicle alike. Phases, in order:

1. ``settle`` s standing, brake on (the localization starts, the recorder catches up);
2. the handlebar steps at ``handlebar_speed``, each held ``handlebar_hold`` s;
3. a linear chirp of the handlebar (``sweep_amplitude``, ``sweep_f0`` to ``sweep_f1`` Hz
   over ``sweep_duration`` s) at the same speed;
4. the speed steps with the handlebar straight, each held ``speed_hold`` s;
5. standstill, brake on, for good.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import List, Tuple

from quadrivio_config import ConfigError, param


@dataclass(frozen=True)
class ExcitationParams:
    settle: float = param(3.0, lo=0.0, hi=60.0, unit="s", doc="standing still before the program")
    handlebar_speed: float = param(1.5, lo=0.3, hi=5.0, unit="m/s", doc="speed during the handlebar steps and sweep")
    handlebar_steps: Tuple[float, ...] = param((0.1, -0.1, 0.3, -0.3, 0.0, 0.4, -0.4, 0.0, 0.05, -0.2, 0.0),
                                         unit="rad", doc="handlebar setpoints in turn")
    handlebar_hold: float = param(2.0, lo=0.5, hi=30.0, unit="s", doc="each handlebar step held this long")
    sweep_amplitude: float = param(0.25, lo=0.0, hi=1.0, unit="rad", doc="chirp amplitude (0: no sweep)")
    sweep_f0: float = param(0.1, lo=0.01, hi=5.0, unit="Hz", doc="chirp start frequency")
    sweep_f1: float = param(1.0, lo=0.01, hi=5.0, unit="Hz", doc="chirp end frequency")
    sweep_duration: float = param(15.0, lo=0.0, hi=300.0, unit="s", doc="chirp length")
    speed_steps: Tuple[float, ...] = param((1.0, 2.5, 1.5, 3.0, 0.0, 2.0, 0.5, 0.0),
                                     unit="m/s", doc="speed setpoints in turn (handlebar straight)")
    speed_hold: float = param(3.0, lo=0.5, hi=60.0, unit="s", doc="each speed step held this long")
    max_speed: float = param(4.0, lo=0.5, hi=10.0, unit="m/s", doc="no setpoint above this (a program error, refused)")
    max_handlebar: float = param(0.6, lo=0.05, hi=1.5, unit="rad", doc="no setpoint beyond this (refused)")
    rate: float = param(50.0, lo=5.0, hi=200.0, unit="Hz", doc="setpoints sent per second")


Row = Tuple[float, float, float, float]  # t [s], speed [m/s], handlebar [rad], brake [1]


class Program:
    """The setpoints in time, from the program's start."""

    def __init__(self, rows: List[Row], sweep: Tuple[float, float, ExcitationParams]) -> None:
        self.rows = rows
        self.times = [r[0] for r in rows]
        self.sweep_t0, self.sweep_t1, self.p = sweep

    @property
    def duration(self) -> float:
        """When the final standstill begins."""
        return self.times[-1]

    def at(self, t: float) -> Tuple[float, float, float]:
        """``(speed, handlebar, brake)`` at ``t`` s from the start (before it: standstill)."""
        p = self.p
        if self.sweep_t0 <= t < self.sweep_t1:
            tau = t - self.sweep_t0
            k = (p.sweep_f1 - p.sweep_f0) / max(p.sweep_duration, 1e-9)
            phase = 2.0 * math.pi * (p.sweep_f0 * tau + 0.5 * k * tau * tau)
            return p.handlebar_speed, p.sweep_amplitude * math.sin(phase), 0.0
        i = bisect.bisect_right(self.times, t) - 1
        if i < 0:
            return 0.0, 0.0, 1.0
        _, v, h, b = self.rows[i]
        return v, h, b


def build(p: ExcitationParams) -> Program:
    """The program of ``p``; a ConfigError names a setpoint beyond the limits."""
    for v in p.speed_steps + (p.handlebar_speed,):
        if not math.isfinite(v) or abs(v) > p.max_speed:
            raise ConfigError(f"excitation: speed {v} m/s is beyond max_speed {p.max_speed}")
    for h in p.handlebar_steps + (p.sweep_amplitude,):
        if not math.isfinite(h) or abs(h) > p.max_handlebar:
            raise ConfigError(f"excitation: handlebar {h} rad is beyond max_handlebar {p.max_handlebar}")
    if not p.handlebar_steps and not p.speed_steps and p.sweep_amplitude == 0.0:
        raise ConfigError("excitation: no handlebar steps, no sweep and no speed steps: nothing to excite")
    rows: List[Row] = [(0.0, 0.0, 0.0, 1.0)]
    t = p.settle
    if p.handlebar_steps or p.sweep_amplitude > 0.0:
        rows.append((t, p.handlebar_speed, 0.0, 0.0))  # get rolling straight first
        t += p.handlebar_hold
        for h in p.handlebar_steps:
            rows.append((t, p.handlebar_speed, h, 0.0))
            t += p.handlebar_hold
    sweep_t0 = sweep_t1 = t
    if p.sweep_amplitude > 0.0 and p.sweep_duration > 0.0:
        sweep_t1 = t + p.sweep_duration
        t = sweep_t1
        rows.append((t, p.handlebar_speed, 0.0, 0.0))
        t += p.handlebar_hold
    for v in p.speed_steps:
        rows.append((t, v, 0.0, 0.0))
        t += p.speed_hold
    rows.append((t, 0.0, 0.0, 1.0))
    return Program(rows, (sweep_t0, sweep_t1, p))
