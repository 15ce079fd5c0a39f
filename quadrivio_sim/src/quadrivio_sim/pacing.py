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

import math
from typing import Callable, Dict, List, Optional


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

    def set_factor(self, rtf: float, sim_t: float, wall: float) -> None:
        """Run at ``rtf`` from the step that starts at ``sim_t``: that step is due when the
        faster of the old and the new factor puts it since the anchor (slowing down, it
        keeps its time; speeding up, it comes sooner), or now when that has passed (no
        burst to catch up with), and the steps after it follow the new factor."""
        if rtf < 0.0:
            raise ValueError(f"real_time_factor must be >= 0, got {rtf}")
        if rtf == self.rtf:
            return
        fast = 0.0 if rtf <= 0.0 or self.rtf <= 0.0 else max(rtf, self.rtf)
        due = wall if fast <= 0.0 else self.wall0 + (sim_t - self.sim0) / fast
        self.rtf = rtf
        self.anchor(sim_t, max(due, wall))

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


class LoopHold:
    """Past the factor the closed loop sustains, wait for it instead of driving on.

    At a factor above 1 a stall of the stack's processes that lasts 100 ms of wall time
    (the 2 cores both busy, a slow update) is 400 ms of sim time at factor 4: the follower
    sends no setpoint for twice the emulated PLC's 200 ms watchdog, the PLC brakes, and
    the run fails on an artefact of the speed-up, not of the stack (bench_endurance: a
    10-minute figure eight at factor 4 braked at 511 s and aborted). At factor 1 the
    simulator stands for the world, which does not wait, and a stall is the stack's own
    fault. So, at other factors, before each step: when the PLC drives (``driving``) and
    the setpoints it depends on are older than ``lag`` sim seconds (``fresh_since``, the
    watchdog's own reference), the simulator serves the PLC link without stepping until a
    fresh setpoint arrives, for at most ``budget`` wall seconds per stall. A client that
    is gone or frozen costs that budget once: then the stall is given up, time runs on and
    the watchdog brakes as it would at factor 1 (never driving on without setpoints)."""

    def __init__(self, lag: float, budget: float) -> None:
        if lag < 0.0 or budget < 0.0:
            raise ValueError(f"loop hold: lag and budget must be >= 0, got {lag}, {budget}")
        self.lag, self.budget = lag, budget
        self.holds = 0  # stalls waited for
        self.held = 0.0  # [s wall] in all
        self.given_up = 0  # stalls whose budget ran out
        self._given_up_at: Optional[float] = None  # fresh_since of the stall given up

    @property
    def enabled(self) -> bool:
        return self.lag > 0.0 and self.budget > 0.0

    def due(self, sim_t: float, fresh_since: float, driving: bool) -> bool:
        """Whether to wait before the step that starts at ``sim_t`` [s sim]."""
        return (self.enabled and driving and sim_t - fresh_since > self.lag
                and self._given_up_at != fresh_since)

    def wait(self, sim_t: float, fresh: Callable[[], float], driving: Callable[[], bool],
             serve: Callable[[float], None], now: Callable[[], float]) -> float:
        """Serve (``serve(timeout)``: the PLC link) until the setpoints are fresh again,
        the PLC stops driving, or the budget is spent; the wall seconds waited."""
        start = now()
        since = fresh()
        self.holds += 1
        while now() - start < self.budget:
            serve(min(0.005, self.budget - (now() - start)))
            if not self.due(sim_t, fresh(), driving()):
                break
        else:
            self.given_up += 1
            self._given_up_at = since
        waited = now() - start
        self.held += waited
        return waited


class StaleSlowdown:
    """Past the factor the stack sustains, run at real time while its estimate is stale.

    The stack's own deadlines are in sim time, sized for real time: the smoother creates a
    keyframe without odometry when the wheel speed has not arrived ``max_wait`` (0.25 s)
    after the keyframe's time; the predictor stops predicting from an estimate older than
    ``max_age``. At factor 5 with both cores busy, a process that waits 50 ms of wall time
    for a core misses 250 ms of sim time: the figure eight at factor 5 had 17-311
    keyframes without odometry per run (0 at factor 1) and a cross-track maximum of
    0.44-1.40 m where factor 1 tracks 0.385. Stopping the clock (what :class:`LoopHold`
    does for the setpoints) would not help here, because these nodes work on sim-time
    timers: a keyframe waiting for its odometry is retried on the next tick, and a
    stopped clock has none. So while the newest message of a watched stream
    (``max_age``: stream -> sim seconds) is older than its limit, the simulator runs at
    real time, where the
    stack keeps its deadlines by design; when every stream is fresh again, it returns to
    its factor. A stream is watched from its first message (no localization running, no
    slowdown), only while the PLC drives, and for at most ``budget`` wall seconds per
    episode: a node that died costs that once, then the run goes on at its factor with
    the stack's own reaction to a lost estimate (the predictor stops, the follower stops,
    the PLC brakes), as at factor 1.

    Most episodes are short (tens of wall ms: a process that waited for a core), and
    dropping all the way to real time for each cost more than it protected: asked for 5,
    the figure eight alternated between 5 and 1 and achieved 2.7-3.0, less than asked for
    4. So an episode first runs at ``fraction`` of the factor (never below real time) and,
    still stale ``escalate`` sim seconds after it began, at real time: in sim time, so that
    how stale the loop's data can get does not grow with the factor (0.1 wall s was 0.56
    sim s at factor 8: cross-track max 0.547 m against 0.385). ``fraction`` 0: real time
    at once."""

    def __init__(self, max_age: Dict[str, float], budget: float, fraction: float = 0.0,
                 escalate: float = 0.0) -> None:
        bad = {k: v for k, v in max_age.items() if not v >= 0.0}
        if bad or not budget >= 0.0:
            raise ValueError(f"stale slowdown: every max age and the budget must be >= 0, got {max_age}, {budget}")
        if not (0.0 <= fraction < 1.0) or not escalate >= 0.0:
            raise ValueError(f"stale slowdown: the fraction must be in [0, 1) and the escalation >= 0 s, got "
                             f"{fraction}, {escalate}")
        self.max_age = {k: float(v) for k, v in max_age.items() if v > 0.0}
        self.budget = float(budget)
        self.fraction = float(fraction)
        self.escalate = float(escalate)
        self.newest: Dict[str, float] = {}  # stream -> stamp of its newest message [s sim]
        self.episodes: Dict[str, int] = {k: 0 for k in self.max_age}  # slowdowns started by each stream
        self.slow_wall = 0.0  # [s wall] at real time in all
        self.given_up = 0  # episodes whose budget ran out
        self.escalated = 0  # episodes that went on to real time
        self._at_real_time = False
        self._since: Optional[float] = None  # wall time the current episode began
        self._since_sim = 0.0  # [s sim] and its sim time
        self._given_up_at: Dict[str, float] = {}  # stream -> its newest stamp when given up

    @property
    def enabled(self) -> bool:
        return bool(self.max_age) and self.budget > 0.0

    @property
    def slow(self) -> bool:
        return self._since is not None

    def seen(self, stream: str, stamp: float) -> None:
        """A message of ``stream`` stamped ``stamp`` [s sim] arrived (any thread)."""
        if stamp > self.newest.get(stream, -math.inf):
            self.newest[stream] = stamp

    def stale(self, sim_t: float) -> List[str]:
        """The streams whose newest message is older than their limit at ``sim_t``."""
        out = []
        for name, age in self.max_age.items():
            t = self.newest.get(name)
            if t is not None and sim_t - t > age and self._given_up_at.get(name) != t:
                out.append(name)
        return out

    def factor(self, rtf: float, sim_t: float, driving: bool, wall: float) -> float:
        """The factor for the next step: ``rtf``; while a stream is stale ``fraction`` of it
        for the episode's first ``escalate`` sim seconds, then real time (1). ``rtf`` 0
        means as fast as possible: stale, it runs at real time."""
        if not self.enabled or not (rtf == 0.0 or rtf > 1.0):
            return rtf
        stale = self.stale(sim_t) if driving else []
        if not stale:
            self._end(wall)
            return rtf
        if self._since is None:
            self._since, self._since_sim = wall, sim_t
            for name in stale:
                self.episodes[name] += 1
        elif wall - self._since > self.budget:
            self.given_up += 1
            for name in stale:
                self._given_up_at[name] = self.newest[name]
            self._end(wall)
            return rtf
        if self.fraction > 0.0 and rtf > 0.0 and sim_t - self._since_sim < self.escalate:
            return max(1.0, self.fraction * rtf)
        if not self._at_real_time:
            self._at_real_time = True
            self.escalated += 1
        return 1.0

    def _end(self, wall: float) -> None:
        if self._since is not None:
            self.slow_wall += wall - self._since
            self._since = None
            self._at_real_time = False
