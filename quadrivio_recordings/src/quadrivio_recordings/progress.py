"""Progress of a tool reading a long recording (ROS-free).

A field recording runs for hours, and a tool that reads it whole (``analyze``,
``calibrate``, ``calibrate_mag``) would say nothing for minutes. :class:`BagProgress`
prints, for a recording of at least ``min_span`` seconds, how much of it has been read at
most every ``every`` seconds of wall time, then a line per phase. A short recording (every
simulated run) stays silent.
"""

from __future__ import annotations

import sys
import time
from typing import Callable, Optional, TextIO

LONG_BAG_S = 300.0  # [s] of recording from which a tool reports its progress
PROGRESS_S = 5.0  # [s] of wall time between two progress lines at the most


class BagProgress:
    def __init__(self, tool: str, name: str, t_begin: float, span: float, quiet: bool = False,
                 min_span: Optional[float] = None, every: Optional[float] = None, out: Optional[TextIO] = None,
                 clock: Callable[[], float] = time.perf_counter) -> None:
        self.tool, self.name, self.t_begin, self.span = tool, name, t_begin, span
        self.on = not quiet and span >= (LONG_BAG_S if min_span is None else min_span)
        self.every = PROGRESS_S if every is None else every
        self.out, self.clock = out, clock
        self.t0 = self.said = clock()

    @classmethod
    def of_bag(cls, tool: str, name: str, bag, **kw) -> "BagProgress":
        """For an open rosbag.Bag: its start time and span."""
        if bag.get_message_count():
            return cls(tool, name, bag.get_start_time(), bag.get_end_time() - bag.get_start_time(), **kw)
        return cls(tool, name, 0.0, 0.0, **kw)

    def _print(self, text: str) -> None:
        print(f"[{self.tool}] {text}", file=self.out or sys.stderr, flush=True)

    def update(self, t_read: float) -> None:
        """``t_read``: the recording time [s] of the message just read."""
        if not self.on:
            return
        now = self.clock()
        if now - self.said >= self.every:
            self.said = now
            done = max(0.0, min(1.0, (t_read - self.t_begin) / self.span))
            self._print(f"reading {self.name}: {100 * done:3.0f} % of {self.span:.0f} s recorded, "
                        f"{now - self.t0:.0f} s")

    def phase(self, text: str) -> None:
        """A line for the next phase (long recordings only), with the time so far."""
        if self.on:
            self._print(f"{text} ({self.clock() - self.t0:.0f} s so far)")
