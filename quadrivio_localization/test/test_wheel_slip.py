"""Wheels that report motion the IMU and the GPS deny (quadrivio_localization.wheel_slip),
on synthetic streams; offline against an unmapped wall (the stuck-wheel case):
test/test_stuck_wall.py."""
import math

import numpy as np

from quadrivio_localization.wheel_slip import G, SlipParams, WheelSlip


def drive(ws, t0, t1, wheel, body_accel, pitch=0.0, fixes=None, rng=None, dt=0.01):
    """Feed wheel speeds (50 Hz), IMU (100 Hz, f_x = a - g sin(pitch)) and fixes (5 Hz) from
    ``wheel(t)``, ``body_accel(t)`` and ``fixes(t) -> (e, n)``; returns the slip states at 20 Hz."""
    out = []
    k0, k1 = int(round(t0 / dt)), int(round(t1 / dt))
    for k in range(k0, k1):
        t = k * dt
        ws.add_imu(t, (body_accel(t) - G * math.sin(pitch), 0.0, G * math.cos(pitch)), (0.0, 0.0, 0.0))
        if k % 2 == 0:
            ws.add_speed(t, wheel(t))
        if fixes is not None and k % 20 == 0:
            e, n = fixes(t)
            noise = rng.normal(0.0, 0.3, 2) if rng is not None else (0.0, 0.0)
            ws.add_fix(t, e + noise[0], n + noise[1], 0.09)
        if k % 5 == 0:
            out.append((t, ws.update(t)))
    return out


def test_consistent_driving_is_no_slip():
    ws = WheelSlip()
    rng = np.random.default_rng(0)
    # speed up at 1.5 m/s^2 to 3 m/s, cruise, brake at 3 m/s^2, on a 5 deg slope; fixes follow
    def v(t):
        return min(1.5 * t, 3.0) if t < 8.0 else max(3.0 - 3.0 * (t - 8.0), 0.0)

    def a(t):
        return (1.5 if t < 2.0 else 0.0) if t < 8.0 else (-3.0 if t < 9.0 else 0.0)

    def x(t):  # the integral of v
        if t < 2.0:
            return 0.75 * t * t
        if t < 8.0:
            return 3.0 + 3.0 * (t - 2.0)
        s = min(t - 8.0, 1.0)
        return 21.0 + 3.0 * s - 1.5 * s * s

    states = drive(ws, 0.0, 12.0, v, a, pitch=math.radians(5), fixes=lambda t: (x(t), 0.0), rng=rng)
    assert not any(s for _, s in states)
    assert ws.slips == 0


def test_wheel_spin_up_without_the_body_is_a_slip_within_the_window():
    ws = WheelSlip()
    # standing against a wall: the wheel spins up to 1.4 m/s over 0.4 s from t = 5, the body stays
    wheel = lambda t: 0.0 if t < 5.0 else min(3.5 * (t - 5.0), 1.4)  # noqa: E731
    states = drive(ws, 0.0, 8.0, wheel, lambda t: 0.0, fixes=lambda t: (0.0, 0.0))
    first = next(t for t, s in states if s)
    assert 5.0 < first <= 5.0 + SlipParams().window + 0.05
    assert all(s for t, s in states if t > first)  # it holds while the wheel spins
    assert "the wheel speed changed by +" in ws.reason and "IMU" in ws.reason
    assert any("wheels slip at" in e for e in ws.pop_events())


def test_an_impact_with_the_wheel_turning_on_is_a_slip():
    ws = WheelSlip()
    # 1.5 m/s, the body stops within 0.1 s at t = 4 (a wall), the wheel keeps turning
    states = drive(ws, 0.0, 6.0, lambda t: 1.5, lambda t: -15.0 if 4.0 <= t < 4.1 else 0.0,
                   fixes=lambda t: (1.5 * min(t, 4.05), 0.0))
    first = next(t for t, s in states if s)
    assert 4.0 < first <= 4.55


def test_the_fixes_deny_what_the_imu_cannot_see():
    # a slow creep into a slip (no sharp change for the IMU): the wheel reads 1.4 m/s, the
    # fixes stand still; the GPS test catches it once the window is full
    ws = WheelSlip(SlipParams(threshold=0.5))
    rng = np.random.default_rng(1)
    states = drive(ws, 0.0, 6.0, lambda t: min(0.2 * t, 1.4), lambda t: 0.0, fixes=lambda t: (10.0, 5.0), rng=rng)
    first = next((t for t, s in states if s), None)
    assert first is not None and "GPS fixes" in ws.reason


def test_inconsistent_fixes_decide_nothing():
    # a multipath burst (a 6 m jump) inside the window: the fixes are not one steady stream
    ws = WheelSlip()
    rng = np.random.default_rng(2)
    drive(ws, 0.0, 4.0, lambda t: 1.0, lambda t: 0.0, fixes=lambda t: (t + (6.0 if t > 2.5 else 0.0), 0.0), rng=rng)
    assert ws.gps_speed(3.9) is None


def test_a_slip_ends_when_the_wheel_rests_or_the_fixes_agree():
    ws = WheelSlip()
    wheel = lambda t: 0.0 if t < 2.0 else (1.4 if t < 6.0 else 0.0)  # noqa: E731
    states = drive(ws, 0.0, 7.0, wheel, lambda t: 0.0, fixes=lambda t: (0.0, 0.0))
    assert any(s for t, s in states if 3.0 < t < 5.9)
    assert not any(s for t, s in states if t > 6.1)
    assert any("the wheel reads rest" in e for e in ws.pop_events())
    # the tyres find grip: the body accelerates to the wheel's speed (IMU), the fixes follow
    ws = WheelSlip()
    x = {"v": 0.0, "x": 0.0}

    def body_a(t):
        return 0.0 if t < 3.0 else (1.4 if t < 4.0 else 0.0)

    def fixes(t):
        v = 0.0 if t < 3.0 else min(1.4 * (t - 3.0), 1.4)
        xx = 0.0 if t < 3.0 else (0.7 * (t - 3.0) ** 2 if t < 4.0 else 0.7 + 1.4 * (t - 4.0))
        x["v"], x["x"] = v, xx
        return xx, 0.0
    states = drive(ws, 0.0, 8.0, lambda t: 0.0 if t < 2.0 else 1.4, body_a, fixes=fixes)
    assert any(s for t, s in states if 2.5 < t < 3.0)
    assert not any(s for t, s in states if t > 6.0)


def test_the_threshold_rises_with_the_discrepancy_on_rough_ground():
    # bumps: the wheel speed wanders 0.3 m/s about the body's 2 m/s (correlated over 0.2 s);
    # a fixed threshold of 0.7 m/s is 2.3 of the difference's sds: it fired on bumps
    rng = np.random.default_rng(3)
    knots = rng.normal(0.0, 0.3, 400)

    def wheel(t):  # at rest, 2 m/s^2 to 2 m/s from t = 1, the bumps from t = 3
        return min(max(2.0 * (t - 1.0), 0.0), 2.0) + (float(np.interp(t, np.arange(400) * 0.2, knots)) if t > 3.0 else 0.0)

    def body_a(t):
        return 2.0 if 1.0 <= t < 2.0 else 0.0
    ws = WheelSlip()
    states = drive(ws, 0.0, 60.0, wheel, body_a)
    assert not any(s for t, s in states if t > 14.0)  # once its RMS is learnt (10 s)
    fixed = WheelSlip(SlipParams(sigmas=0.0))
    assert any(s for _, s in drive(fixed, 0.0, 60.0, wheel, body_a))  # the case it guards against
    # on that ground a wall still stops the body while the wheel turns on
    states = drive(ws, 60.0, 63.0, lambda t: wheel(t) if t < 61.0 else 2.0, lambda t: -20.0 if 61.0 <= t < 61.1 else 0.0)
    first = next(t for t, s in states if s)
    assert 61.0 < first <= 61.55
    assert math.sqrt(ws.noise_ms) > 0.2


def test_the_imu_lever_arm_is_no_speed_change():
    # an IMU 0.25 m above base_link on a body pitching +-5 deg at 1 Hz at a steady 2 m/s: the
    # specific force holds alpha x r (0.27 m/s of "speed change" over 0.5 s), the body's
    # speed does not change
    r = (0.55, 0.0, 0.25)
    amp, om = math.radians(5.0), 2.0 * math.pi

    def largest_change(lever):
        ws = WheelSlip(lever=lever)
        changes = []
        for k in range(0, 2000):
            t = k * 0.01
            p, q, dq = amp * math.sin(om * t), amp * om * math.cos(om * t), -amp * om * om * math.sin(om * t)
            # at base_link: gravity and w x v (along z); at the IMU + alpha x r + w x (w x r), w = (0, q, 0)
            f = (-G * math.sin(p) + dq * r[2] - q * q * r[0], 0.0, G * math.cos(p) + q * 2.0 - dq * r[0] - q * q * r[2])
            ws.add_imu(t, f, (0.0, q, 0.0))
            if k % 2 == 0:
                ws.add_speed(t, 2.0)
            if t > 10.0 and k % 5 == 0:  # the filter settled (it starts on a sample of about 1 g)
                changes.append(abs(ws.body_change(t - 0.5, t)))
        return max(changes)
    # what is left: the attitude filter's pitch (1.2-1.6 deg off: its pull sees alpha x r too)
    assert largest_change(r) < 0.2
    assert largest_change((0.0, 0.0, 0.0)) > 0.3  # the lever ignored
