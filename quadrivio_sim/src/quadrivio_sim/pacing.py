"""Pacing sim time against the wall clock at a real-time factor.

The simulator steps, then asks the pacer how long to wait before the next step. A step
that came late (the process was descheduled, a ray batch took long) is made up by running
the next steps without waiting, but only up to ``max_lag`` seconds of sim time: beyond
that the pacer drops the lost time and re-anchors. Catching up compresses sim time for
every other node, and those run on the wall clock: at factor 2 a 100 ms stall made up in
one burst advances sim time by 200 ms in a few milliseconds, long enough for the emulated
PLC's 200 ms watchdog to find no frame from a client that had no chance to send one.
Gazebo behaves the same way: it sleeps when ahead and never races to recover lost time.
"""

from __future__ import annotations


class Pacer:
    def __init__(self, real_time_factor: float, max_lag: float) -> None:
        if real_time_factor < 0.0:
            raise ValueError(f"real_time_factor must be >= 0, got {real_time_factor}")
        if max_lag < 0.0:
            raise ValueError(f"max_lag must be >= 0, got {max_lag}")
        self.rtf = real_time_factor
        self.max_lag = max_lag
        self.wall0 = self.sim0 = 0.0
        self.dropped = 0.0  # sim seconds given up so far
        self.drops = 0

    def anchor(self, sim_t: float, wall: float) -> None:
        """Sim time ``sim_t`` is now, on the wall clock, ``wall``."""
        self.sim0, self.wall0 = sim_t, wall

    def wait(self, sim_t: float, wall: float) -> float:
        """Wall seconds to wait before the step that starts at ``sim_t`` (0: at once).
        With factor 0 (as fast as possible) never waits."""
        if self.rtf <= 0.0:
            return 0.0
        ahead = self.wall0 + (sim_t - self.sim0) / self.rtf - wall
        if ahead >= 0.0:
            return ahead
        lag = -ahead * self.rtf  # sim seconds behind the schedule
        if lag > self.max_lag:
            self.dropped += lag
            self.drops += 1
            self.anchor(sim_t, wall)
        return 0.0
