"""Timed setpoint scripts: open-loop inputs applied in sim time.

A script drives the emulated PLC as the autonomous source, so that the same script
and seed give the same run (determinism tests), and recorded setpoints can be fed
back into the simulator (``calibrate --replay``, the paper's section 3.2 procedure).

File format: CSV (``#`` lines are comments) with a header naming at least ``t`` and any of ``speed``
[m/s], ``handlebar`` [rad], ``brake`` [1] (missing columns are 0), or YAML with a
``setpoints`` list of ``{t, speed, handlebar, brake}``. Values are held (zero-order
hold) from their time until the next row's.
"""

from __future__ import annotations

import bisect
import csv
import math
import os
from dataclasses import dataclass
from typing import List, Sequence, Tuple

from quadrivio_config import ConfigError, load_yaml


@dataclass(frozen=True)
class ScriptRow:
    t: float  # [s]
    speed: float  # [m/s]
    handlebar: float  # [rad]
    brake: float  # [1]


class SetpointScript:
    def __init__(self, rows: Sequence[ScriptRow], source: str = "script") -> None:
        if not rows:
            raise ConfigError(f"{source}: the setpoint script is empty")
        times = [r.t for r in rows]
        if any(b < a for a, b in zip(times, times[1:])):
            raise ConfigError(f"{source}: setpoint times must not decrease")
        for r in rows:
            if not all(math.isfinite(v) for v in (r.t, r.speed, r.handlebar, r.brake)):
                raise ConfigError(f"{source}: row at t = {r.t} has a value that is not a finite number")
        self.rows = list(rows)
        self.times = times
        self.source = source

    @property
    def end(self) -> float:
        return self.times[-1]

    def at(self, t: float) -> Tuple[float, float, float]:
        """``(speed, handlebar, brake)`` held at time ``t``; before the first row: zeros."""
        i = bisect.bisect_right(self.times, t) - 1
        if i < 0:
            return 0.0, 0.0, 0.0
        r = self.rows[i]
        return r.speed, r.handlebar, r.brake


def load_script(path: str) -> SetpointScript:
    if not os.path.isfile(path):
        raise ConfigError(f"setpoint script {path}: file not found")
    if path.endswith((".yaml", ".yml")):
        data = load_yaml(path)
        items = data.get("setpoints")
        if not isinstance(items, list):
            raise ConfigError(f"setpoint script {path}: needs a 'setpoints' list of {{t, speed, handlebar, brake}}")
        rows: List[ScriptRow] = []
        for k, item in enumerate(items):
            try:
                rows.append(ScriptRow(float(item["t"]), float(item.get("speed", 0.0)),
                                      float(item.get("handlebar", 0.0)), float(item.get("brake", 0.0))))
            except (KeyError, TypeError, ValueError) as exc:
                raise ConfigError(f"setpoint script {path}: entry {k} is malformed ({exc})") from exc
        return SetpointScript(rows, path)
    with open(path, newline="", encoding="utf-8") as fh:
        reader = csv.DictReader(line for line in fh if not line.lstrip().startswith("#"))
        if reader.fieldnames is None or "t" not in reader.fieldnames:
            raise ConfigError(f"setpoint script {path}: the CSV header must name a 't' column")
        rows = []
        for line, rec in enumerate(reader, start=2):
            try:
                rows.append(ScriptRow(float(rec["t"]), float(rec.get("speed") or 0.0),
                                      float(rec.get("handlebar") or 0.0), float(rec.get("brake") or 0.0)))
            except ValueError as exc:
                raise ConfigError(f"setpoint script {path}, line {line}: {exc}") from exc
    return SetpointScript(rows, path)
