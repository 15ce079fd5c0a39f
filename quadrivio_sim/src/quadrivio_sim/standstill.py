"""The PLC's standstill monitor: whether the vehicle stands, from the wheel encoder and the
PLC's accelerometer, before a driving mode may be entered again (PROTOCOL.md, "Re-entry").

The wheel alone cannot say it. Braked hard, the rear wheel locks and reads 0 while the body
slides on: after a watchdog trip at 2 m/s the wheel read 0 after 0.16 s with the body still
at 1.2-1.3 m/s, and a driving mode granted then drove on from there. So from the moment the
PLC brakes for a stop (a stop request, a watchdog trip, a lost session) with the wheel
turning, the body's speed is carried by the accelerometer instead::

    v_body(t) = v_wheel(t_stop) + integral from t_stop to t of (f_x - b) dt

``f_x`` is the specific force along the body's x axis; ``b`` is what ``f_x`` reads when the
body does not accelerate (gravity along a slope, the sensor's own bias), learnt while the
wheel was trusted as a low-pass of ``f_x - dv_wheel/dt``. Friction never reverses a slide,
so ``v_body`` stops at zero, and is not integrated after that (the braked body rocks on
its springs and stands pitched otherwise than it drove: integrating that only drifts; a
stop read early by a pitch error during the slide is covered by the hold). Standstill is verified when the wheel reads at most
``wheel_speed`` and ``v_body`` is at most ``body_speed``, both for ``hold`` s without a break;
the wheel is trusted again from then. Without an accelerometer (``f_x`` NaN), or when its
integral has drifted, the wheel at rest for ``slide_timeout`` s after the stop is taken as
standstill: longer than any slide from the vehicle's top speed at the weakest braking it
meets (the monitor's one assumption, written in PROTOCOL.md).

At power-on the vehicle is taken to be standing (the wheel confirms it at once: a turning
wheel breaks the hold). Pure: no ROS, no simulator; times are PLC clock seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import List, Optional, Tuple

from quadrivio_config import param


@dataclass(frozen=True)
class StandstillParams:
    wheel_speed: float = param(0.05, lo=0.0, hi=1.0, unit="m/s", doc="the wheel reads at most this at standstill")
    body_speed: float = param(0.1, lo=0.0, hi=1.0, unit="m/s",
                              doc="the body's speed from the accelerometer is at most this at standstill")
    hold: float = param(0.5, lo=0.0, hi=10.0, unit="s", doc="both hold for this long without a break")
    slide_timeout: float = param(4.0, lo=0.1, hi=60.0, unit="s",
                                 doc="after a stop, the wheel at rest this long is standstill whatever the "
                                     "accelerometer says (no accelerometer, or its integral drifted): longer "
                                     "than any slide from the top speed at the weakest braking")
    bias_time: float = param(1.0, lo=0.01, hi=60.0, unit="s",
                             doc="time constant of the accelerometer's rest reading learnt while the wheel is trusted")


class StandstillMonitor:
    """See module docstring. ``update`` every PLC cycle; ``braking`` when the PLC brakes for a
    stop; ``verified`` before entering a driving mode."""

    def __init__(self, params: StandstillParams) -> None:
        self.p = params
        self.reset(0.0)

    def reset(self, t: float) -> None:
        self.t_prev: Optional[float] = None
        self.wheel = 0.0
        self.v_body = 0.0
        self.bias: Optional[float] = None  # f_x at no acceleration
        self.inertial = False  # the wheel is not trusted: v_body from the accelerometer
        self.stop_at = -math.inf  # PLC time of the last stop with the wheel turning
        self.rest_since: Optional[float] = -math.inf  # both at rest since (power-on: standing)
        self.wheel_rest_since: Optional[float] = -math.inf
        self.events: List[str] = []

    # ------------------------------------------------------------------ inputs
    def update(self, t: float, wheel_speed: float, accel_x: float = math.nan) -> None:
        """One cycle: the wheel speed [m/s] and the accelerometer's x specific force [m/s^2]."""
        if not math.isfinite(wheel_speed):
            wheel_speed = math.inf  # an encoder that reads nothing proves no standstill
        dt = 0.0 if self.t_prev is None else t - self.t_prev
        if dt < 0.0:  # the clock moved back (a reset): start over
            self.reset(t)
            dt = 0.0
        has_imu = math.isfinite(accel_x)
        if not self.inertial:
            if has_imu and dt > 0.0 and math.isfinite(self.wheel) and math.isfinite(wheel_speed):
                rest_reading = accel_x - (wheel_speed - self.wheel) / dt
                if self.bias is None:
                    self.bias = rest_reading
                else:
                    self.bias += min(1.0, dt / self.p.bias_time) * (rest_reading - self.bias)
            self.v_body = wheel_speed
        elif has_imu and self.bias is not None and dt > 0.0 and self.v_body != 0.0:
            # Until the slide has stopped: after that the braked body rocks on its springs
            # and stands pitched otherwise than it drove, and integrating that would only
            # drift; the hold time covers a stop read a little early.
            v = self.v_body + (accel_x - self.bias) * dt
            self.v_body = 0.0 if v * self.v_body <= 0.0 else v  # a slide stops; it never reverses
        self.t_prev, self.wheel = t, wheel_speed
        wheel_rest = abs(wheel_speed) <= self.p.wheel_speed
        if not wheel_rest:
            self.wheel_rest_since = None
        elif self.wheel_rest_since is None:
            self.wheel_rest_since = t
        at_rest = wheel_rest and (abs(self.v_body) <= self.p.body_speed or not self.inertial)
        if not at_rest:
            self.rest_since = None
        elif self.rest_since is None:
            self.rest_since = t
        if self.inertial:
            if self.rest_since is not None and t - self.rest_since >= self.p.hold:
                self.inertial = False
                self.events.append(f"standstill verified {t - self.stop_at:.2f} s after the stop (wheel "
                                   f"{wheel_speed:.2f} m/s, body {self.v_body:.2f} m/s from the accelerometer, "
                                   f"for {self.p.hold} s)")
                self.v_body = wheel_speed
            elif self.wheel_rest_since is not None and t - self.stop_at >= self.p.slide_timeout and \
                    t - self.wheel_rest_since >= self.p.hold:
                self.events.append(f"standstill taken from the wheel alone {t - self.stop_at:.2f} s after the "
                                   f"stop (slide_timeout {self.p.slide_timeout} s): the accelerometer's speed "
                                   f"{'is unknown' if self.bias is None else f'read {self.v_body:.2f} m/s'}")
                self.inertial = False
                self.v_body = wheel_speed
                self.rest_since = self.wheel_rest_since

    def braking(self, t: float) -> None:
        """The PLC brakes for a stop: from now on, until standstill is verified, the wheel may lock."""
        if abs(self.wheel) > self.p.wheel_speed or self.inertial:
            if not self.inertial:
                self.stop_at = t
            self.inertial = True
            self.rest_since = None

    # ------------------------------------------------------------------ output
    def verified(self, t: float) -> Tuple[bool, str]:
        """(whether the vehicle stands, verified; if not, why in words)."""
        if self.rest_since is not None and not self.inertial and t - self.rest_since >= self.p.hold:
            return True, ""
        parts = [f"wheel {self.wheel:.2f} m/s"]
        if self.inertial:
            parts.append(f"body {self.v_body:.2f} m/s from the accelerometer" if self.bias is not None
                         else "body speed unknown (no accelerometer)")
            parts.append(f"{t - self.stop_at:.2f} s after the stop")
        if self.rest_since is not None:
            parts.append(f"at rest for {t - self.rest_since:.2f} of {self.p.hold} s")
        return False, "; ".join(parts)

    def pop_events(self) -> List[str]:
        ev, self.events = self.events, []
        return ev
