"""The smoother on simulated sensors: accuracy, self-calibration, faults, robustness."""
import dataclasses
import math
import os

import numpy as np
import pytest
import yaml

from offline_run import resting_script, run
from quadrivio_config import from_mapping, replace_nested
from quadrivio_description.site import load_site
from quadrivio_description.vehicle import load_vehicle
from quadrivio_localization.smoother import Localizer, LocalizerParams


def rmse(x):
    return float(np.sqrt(np.mean(np.square(x))))


@pytest.fixture(scope="module")
def calibrated_run():
    """Measurements with known calibration errors: wheel speed 5 % high, handlebar 0.03 rad
    off, 0.005 rad/s of extra gyro bias; the magnetometer's hard/soft iron from mag.yaml."""
    return run(seconds=120.0, speed_scale=1.05, handlebar_offset=0.03, gyro_bias=0.005)


def test_accuracy_after_convergence(calibrated_run):
    errors, _, _ = calibrated_run
    settled = errors[errors[:, 0] > 40.0]
    # [m] the GPS drifts 0.15 m per axis (0.21 m RMS horizontally), which nothing else can
    # see: this seed's drift sets 0.29-0.31 m (random-walk and Gauss-Markov drift models)
    assert rmse(settled[:, 1]) < 0.35
    assert rmse(settled[:, 2]) < 1.0  # [deg]


def test_self_calibration_converges(calibrated_run):
    _, loc, est = calibrated_run
    c = est.calibration
    assert c["wheel_speed_scale"] == pytest.approx(1 / 1.05, rel=0.01)
    assert c["handlebar_offset"] == pytest.approx(-0.03, abs=0.005)
    assert c["gyro_bias"] == pytest.approx(0.005, abs=0.004)  # plus the IMU's own turn-on bias (3e-3 rad/s std)
    # mag.yaml: hard iron (4.0, -2.5) uT, soft iron [[1.05, 0.03], [0.03, 0.96]]
    assert c["mag_hard_iron_x"] == pytest.approx(4.0, abs=0.8)
    assert c["mag_hard_iron_y"] == pytest.approx(-2.5, abs=0.8)
    assert c["mag_soft_iron_xx"] == pytest.approx(1.05, abs=0.03)
    assert c["mag_soft_iron_yy"] == pytest.approx(0.96, abs=0.03)
    assert c["mag_soft_iron_xy"] == pytest.approx(0.03, abs=0.02)
    sigma = loc.calibration_sigma()
    assert 0 < sigma["wheel_speed_scale"] < 0.01 and 0 < sigma["handlebar_offset"] < 0.01


def test_estimate_is_consistent(calibrated_run):
    """The reported covariance covers the error: the position error's squared Mahalanobis
    distance (NEES) is within the 2-D 3-sigma bound (chi-square 11.83, 99.73 %) at nearly
    every settled epoch, and its mean is near 2 (the dimension): neither overconfident
    nor uselessly loose. The heading error is within 3 sigma too."""
    errors, loc, est = calibrated_run
    assert np.all(np.linalg.eigvalsh(est.covariance) > 0)
    settled = errors[errors[:, 0] > 40.0]
    nees = []
    for row in settled:
        e = row[4:6]
        cov = np.array([[row[6], row[7]], [row[7], row[8]]])
        nees.append(float(e @ np.linalg.solve(cov, e)))
    nees = np.array(nees)
    assert len(nees) > 500
    assert np.mean(nees <= 11.83) >= 0.97, f"{np.mean(nees <= 11.83):.3f} of epochs within 3 sigma"
    # The settled error is mostly the receiver's drift (0.15 m, correlated over 120 s):
    # over these 80 s it is about one sample of a 2-dof chi-square, so its mean NEES is
    # noisy (3.x with fixes used 1 s late, 4.1 with this receiver's fixes used at once);
    # the 3-sigma fraction above is the sharper test.
    assert 0.5 <= np.mean(nees) <= 5.0, f"mean NEES {np.mean(nees):.2f} (2 for a consistent estimate)"
    assert np.mean(np.abs(settled[:, 2]) <= 3.0 * settled[:, 3]) >= 0.97
    assert math.sqrt(est.covariance[0, 0]) < 0.5


@pytest.mark.parametrize("calibrated", [False, True])
def test_heading_holds_at_rest(calibrated):
    """At rest only the magnetometer knows north. Uncalibrated (hard iron sigma 15 uT against
    a 24 uT horizontal field) the heading is uncertain by tens of degrees, and the reported
    sigma must say so; with a calibration from recorded data it is good to a degree. Either
    way the estimate must settle, not wander (linearised marginals of too many, too
    confident magnetometer factors used to drag it 45 degrees in 5 s)."""
    params = LocalizerParams()
    if calibrated:  # what calibrate_mag fits to a drive in circles (mag.yaml: o = (4, -2.5), S ~ 1.05, 0.96, 0.03)
        params = replace_nested(params, {"priors": {"magnetometer": {
            "hard_iron": (4.2, -2.3), "hard_iron_sigma": 0.5, "soft_iron": (1.045, 0.965, 0.028),
            "soft_iron_sigma": (0.01, 0.01, 0.01)}}})
    errors, _, _ = run(seconds=30.0, params=params, script=resting_script)
    late = errors[errors[:, 0] > 5.0]
    # Settled: it moves much less than it is uncertain (it used to wander by 45 degrees
    # while claiming 9), and the uncertainty does not shrink on no new information.
    # (Uncalibrated, 12 degrees of settling against 33 of sigma were seen: the antenna's
    # 0.15 m lever arm lets the fixes say a little about the heading even at rest.)
    assert np.ptp(late[:, 2]) < 0.5 * late[:, 3].min()
    assert late[:, 3].min() > 0.8 * late[0, 3]
    assert np.all(np.abs(errors[:, 2]) < 3.0 * errors[:, 3])  # consistent
    if calibrated:
        assert np.abs(late[:, 2]).max() < 2.0  # [deg]
    else:
        assert late[:, 3].min() > 20.0  # [deg] 15 uT of unknown hard iron against 24 uT: honest about it


def test_multipath_is_rejected_and_outages_bridged():
    def faulty(noise):
        return replace_nested(noise, {"multipath": {"mean_interval": 15.0, "duration_mean": 4.0, "offset_scale": 4.0},
                                      "outages": {"scheduled": [[50.0, 62.0]]}})
    errors, loc, _ = run(seconds=90.0, gps_changes=faulty, seed=3)
    settled = errors[errors[:, 0] > 30.0]
    assert loc.gate.counts["outlier"] + loc.gate.counts["multipath"] > 10  # multipath bursts of metres
    assert loc.gate.counts["no fix"] >= 55  # 12 s of outage at 5 Hz
    assert rmse(settled[:, 1]) < 0.5
    outage = errors[(errors[:, 0] > 50.0) & (errors[:, 0] < 62.0)]
    assert outage[:, 1].max() < 1.0  # 12 s on odometry, gyro and magnetometer alone


def test_small_multipath_jumps_are_caught():
    """A 1.2 m burst is within the single-fix gate of a settled estimate: the multipath test
    (the fixes of the next second together) must catch it, let the estimate ride on
    odometry through it, and take the fixes back when the burst ends."""
    def burst(noise):
        return replace_nested(noise, {"multipath": {"scheduled": [[40.0, 52.0]], "offset_scale": 1e-9}})

    import quadrivio_sim.noise as N

    original = N.GpsNoise.apply

    def apply(self, t, position, velocity):  # a fixed 1.2 m east offset during the scheduled burst
        r = original(self, t, position, velocity)
        if r.multipath and r.position is not None:
            p = list(r.position)
            p[0] += 1.2
            r = N.GpsReading(r.stamp, r.status, tuple(p), r.velocity, r.variances, r.multipath, r.satellites, r.hdop)
        return r

    N.GpsNoise.apply = apply
    try:
        errors, loc, _ = run(seconds=70.0, gps_changes=burst, seed=4)
    finally:
        N.GpsNoise.apply = original
    # Exactly the burst's 12 s at 5 Hz rejected: none before it, none once it ended.
    rejected = loc.gate.counts["multipath"] + loc.gate.counts["outlier"]
    assert loc.gate.yielded == 0 and 55 <= rejected <= 61, loc.gate.summary()
    during = errors[(errors[:, 0] > 40.0) & (errors[:, 0] < 52.0)]
    after = errors[errors[:, 0] > 55.0]
    # The receiver's drift keeps this run 0.3-0.43 m off, burst or not: not dragged 1.2 m.
    assert during[:, 1].max() < 0.5 and after[:, 1].max() < 0.5


def _offset_burst(start, end, east):
    """(gps_changes, GpsNoise.apply patch) for a burst of ``east`` m from ``start`` to ``end`` s."""
    import quadrivio_sim.noise as N

    def changes(noise):
        return replace_nested(noise, {"multipath": {"scheduled": [[start, end]], "offset_scale": 1e-9}})

    original = N.GpsNoise.apply

    def apply(self, t, position, velocity):
        r = original(self, t, position, velocity)
        if r.multipath and r.position is not None:
            p = list(r.position)
            p[0] += east
            r = N.GpsReading(r.stamp, r.status, tuple(p), r.velocity, r.variances, r.multipath, r.satellites, r.hdop)
        return r
    return changes, apply, original


def test_a_burst_before_a_dead_wheel_stays_out():
    """A 3 m burst, and half a second later the wheel-speed channel reads 0 while the vehicle
    drives on for 2.5 s. The dead wheel unsettles the gate (the estimate believed "standing"),
    but the burst began before the fault, while the estimate was trusted: its fixes stay out,
    and the estimate rides the IMU's speed through the blind stretch, not the burst. (On rough
    ground at 3 m/s the burst went in: the blind stretch's motion allowance, 1.5 m/s, made a
    3.2 m offset look like the estimate's own error after 3 s; the estimate ran 3.5 m off and
    then held the true fixes out as a burst.)"""
    import quadrivio_sim.noise as N

    changes, apply, original = _offset_burst(40.0, 50.0, 3.0)
    N.GpsNoise.apply = apply
    try:
        errors, loc, _ = run(seconds=60.0, gps_changes=changes, seed=4, wheel_dead=(40.5, 43.0))
    finally:
        N.GpsNoise.apply = original
    events = " ".join(loc.events)
    assert loc.counters.intervals_wheel_rejected > 20, loc.counters  # the dead wheel was found
    assert loc.gate.bursts >= 1 and loc.gate.yielded == 0, loc.gate.summary()
    during = errors[(errors[:, 0] > 40.0) & (errors[:, 0] < 50.0)]
    after = errors[errors[:, 0] > 52.0]
    # Not dragged 3 m east by the burst: 5.5 s without odometry (the dead channel, then its
    # return taken for a spin-up) leave the IMU's speed to drift it 1.3-1.7 m, west and north.
    assert during[:, 4].max() < 1.0 and during[:, 1].max() < 2.0, (during[:, 4].max(), during[:, 1].max(), events)
    assert after[:, 1].max() < 0.6, after[:, 1].max()  # the fixes back once it ended


def test_bad_input_is_counted_not_fatal():
    loc = Localizer(LocalizerParams(), load_vehicle(), load_site())
    loc.add_vehicle_state(0.0, math.nan, 0.0)
    loc.add_imu(0.0, (0.0, 0.0, math.inf), (0.0, 0.0, 0.0))
    loc.add_gps(0.0, math.nan, 9.0, 100.0, 1.0, 1.0, 2)
    loc.add_vehicle_state(1.0, 1.0, 0.0)
    loc.add_vehicle_state(0.5, 1.0, 0.0)  # out of order
    assert loc.counters.bad_input == 3 and loc.counters.out_of_order == 1
    assert loc.update(2.0) is None  # no fix yet: no estimate, no crash


def test_calibration_off_holds_priors():
    params = dataclasses.replace(LocalizerParams(), calibrate=False)
    _, _, est = run(seconds=30.0, params=params)
    assert est.calibration["wheel_speed_scale"] == pytest.approx(1.0, abs=1e-3)
    assert est.calibration["mag_hard_iron_x"] == pytest.approx(0.0, abs=0.05)


def test_config_file_documents_the_defaults():
    """config/localization.yaml states every default of LocalizerParams (and nothing else)."""
    path = os.path.join(os.path.dirname(__file__), "..", "config", "localization.yaml")
    with open(path) as f:
        d = yaml.safe_load(f)
    for node_key in ("map_frame", "odom_frame", "base_frame", "publish_tf", "calibration_period"):
        d.pop(node_key)
    assert from_mapping(LocalizerParams, d, path) == LocalizerParams()


def test_a_late_magnetometer_is_one_factor_per_slot_as_an_early_one():
    """Readings 150 ms late (a driver's buffering, a node waiting for a core at factor 4):
    each 0.5 s slot must still become one factor of all its readings. Closing a slot one
    keyframe after its end made the late readings a second factor of the same slot (its
    model error counted twice): the figure eight's heading error went 0.20 -> 0.95 deg RMS."""
    on_time, loc0, _ = run(seconds=60.0, seed=2)
    late, loc1, _ = run(seconds=60.0, seed=2, mag_delay=0.15)
    assert loc1.counters.mag_late == 0
    assert abs(loc1.counters.mag_used - loc0.counters.mag_used) <= 1
    s0, s1 = on_time[on_time[:, 0] > 20.0], late[late[:, 0] > 20.0]
    assert rmse(s1[:, 2]) < rmse(s0[:, 2]) + 0.1  # [deg]
    assert rmse(s1[:, 1]) < rmse(s0[:, 1]) + 0.02  # [m]


def test_magnetometer_readings_later_than_max_wait_are_dropped_and_counted():
    params = replace_nested(LocalizerParams(), {"max_wait": 0.25})
    _, loc, _ = run(seconds=20.0, seed=2, mag_delay=1.0, params=params)
    assert loc.counters.mag_late > 0
    assert loc.counters.mag_used > 0  # the slots still close, without the late readings


def test_a_frozen_client_leaves_heading_and_speed_honest():
    """faults_fast's frozen PLC client, offline: the wheel speed stops while the vehicle
    speeds up, the watchdog brakes it, it stands 9.6 s without odometry, then drives on. The
    Leveller extrapolated the last wheel-speed slope through the freeze: a 12.5 deg pitch,
    the magnetometer levelled with it turned the heading 15 deg while the vehicle stood,
    and in CI the fixes that came back after the resume were taken for multipath (the
    localization 3.6 m off in 5 s). And /localization/odom said 1.4 m/s all the while."""
    from offline_run import freeze_script
    gap = (5.0, 14.8)
    errors, loc, _ = run(seconds=21.0, seed=0, script=freeze_script, state_gap=gap)
    at = lambda t: errors[np.searchsorted(errors[:, 0], t)]
    drift = abs(at(gap[1] - 0.1)[2] - at(gap[0])[2])
    assert drift < 5.0, f"heading turned {drift:.1f} deg while the vehicle stood without odometry"
    standing = errors[(errors[:, 0] > 8.0) & (errors[:, 0] < gap[1])]
    assert np.abs(standing[:, 10]).max() < 0.05  # it does stand still
    assert np.abs(standing[:, 9]).max() < 0.2, "the speed reported while standing without odometry"
    after = errors[errors[:, 0] > gap[1]]
    assert after[:, 1].max() < 0.6 and np.abs(after[:, 2]).max() < 5.0
    assert loc.gate.counts["multipath"] == 0 and loc.gate.counts["outlier"] == 0
    assert loc.counters.intervals_without_odometry >= 190


def test_a_locked_wheel_is_not_taken_for_standstill_nor_the_fixes_for_multipath():
    """A full brake from 3 m/s locks the simulated wheels: the wheel speed reads 0 while the
    vehicle slides on at 1.8 m/s. The odometry believed it, fell 0.3 m short of the fixes,
    and the gate took the next fix for a multipath burst (all 16 plc_drive.test runs logged
    one; offline, 39 fixes rejected and 0.54-0.81 m of error, seeds 0-2)."""
    from offline_run import brake_script
    errors, loc, _ = run(seconds=30.0, seed=0, script=brake_script)
    events = loc.pop_events()
    assert loc.counters.intervals_wheel_locked > 0 and any("locked wheel" in e for e in events), events
    assert loc.gate.bursts == 0 and loc.gate.counts["multipath"] == 0, events
    assert errors[errors[:, 0] > 19.0, 1].max() < 0.5


def test_a_full_brake_in_a_turn_is_no_dead_wheel_once_the_vehicle_stands():
    """A protective stop in a curve: a full brake with the handlebar at 0.3 rad from 2.75 m/s.
    The wheel locks and reads 0 while the vehicle slides on, turning, which is what a dead
    wheel-speed channel looks like, and the check named one. It held for the 15 s the
    vehicle stood braked: /diagnostics said "wheel speed reads 0 while the vehicle moves"
    and the smoother ignored the odometry of a standing vehicle. Now the fault ends with the
    lock: by the time the vehicle must have stopped, nothing is wrong with the wheel."""
    from quadrivio_sim.script import ScriptRow, SetpointScript

    def script(seconds):
        return SetpointScript([ScriptRow(0.0, 0.0, 0.0, 0.0), ScriptRow(2.0, 3.0, 0.3, 0.0),
                               ScriptRow(20.0, 0.0, 0.3, 1.0), ScriptRow(35.0, 2.0, 0.3, 0.0)])

    errors, loc, _ = run(seconds=40.0, seed=0, script=script)
    events = loc.pop_events()
    assert any("locked wheel" in e for e in events), events
    assert any("odometry used again" in e for e in events), events
    assert not loc.faults()  # driving again
    # at most the lock's time of it: the lock lasts v / 3 m/s^2 < 1 s, 20 keyframes
    assert loc.counters.intervals_without_odometry <= 25, loc.counters
    assert errors[errors[:, 0] > 19.0, 1].max() < 0.4


def test_a_locked_wheel_in_a_gps_outage_brakes_the_estimate_by_the_imu():
    """The same full brake with no fix from 19.8 to 24 s: the wheel reads 0 from the lock
    on, which is also how a dead wheel-speed channel begins (the vehicle then drives on), so
    the wheel cannot say which. The IMU can: from the lock's onset its speed (the wheel's
    before the drop plus the specific force's integral, gravity out) brakes the estimate
    with the vehicle. Without it (the IMU speed's sd made huge) the estimate keeps the speed
    of the slide until the lock ends: 1.15 m off (7.5 m by 24 s while a dead-wheel fault
    found in the slide outlasted the lock and held the odometry off)."""
    from offline_run import brake_script

    def outage(n):
        return dataclasses.replace(n, outages=dataclasses.replace(n.outages, scheduled=((19.8, 24.0),)))

    def worst(imu_speed_sd):
        p = LocalizerParams()
        p = dataclasses.replace(p, noise=dataclasses.replace(p.noise, imu_speed_sd=imu_speed_sd))
        errors, loc, _ = run(seconds=24.5, seed=0, script=brake_script, gps_changes=outage, params=p)
        assert loc.counters.intervals_wheel_locked > 0 and loc.counters.intervals_imu_speed > 0
        return errors[(errors[:, 0] > 19.5) & (errors[:, 0] < 24.0), 1].max()
    assert worst(LocalizerParams().noise.imu_speed_sd) < 0.6
    assert worst(100.0) > 0.9


def test_no_wheel_lock_in_ordinary_driving(calibrated_run):
    _, loc, _ = calibrated_run
    assert loc.counters.intervals_wheel_locked == 0


def test_a_wheel_lock_is_one_event_and_ends_when_the_wheel_turns_or_the_vehicle_must_have_stopped():
    """plc_drive's full brake at 50 Hz states: the drop comes in steps of 0.02 s. Each step
    is judged once: re-reading a step against the floor later steps had set released the
    lock and named a new one per keyframe."""
    def localizer_with(speeds):
        loc = Localizer(LocalizerParams(), load_vehicle(), load_site())
        for t, v in speeds:
            loc.add_vehicle_state(t, v, 0.0)
        return loc

    braking = [(21.16 + 0.02 * i, v) for i, v in enumerate([2.9, 2.8, 2.7, 2.6, 2.39, 1.97, 1.31, 0.5, 0.0, 0.0,
                                                              0.0, 0.0, 0.0])]
    loc = localizer_with(braking + [(21.42, 0.3), (21.44, 0.6)])  # released, then it turns again
    locked = [loc._wheel_locked(t0, t0 + 0.05) for t0 in (21.20, 21.25, 21.30, 21.35, 21.40)]
    assert locked == [False, True, True, True, False]
    assert len([e for e in loc.pop_events() if "locked wheel" in e]) == 1
    # the wheel stays at 0: the lock ends once the vehicle would have stopped at 3 m/s^2 from
    # the speed before the drop (2.39-2.7 m/s: the drop is measured over a keyframe interval)
    loc = localizer_with(braking + [(21.42 + 0.02 * i, 0.0) for i in range(60)])
    ends = [t0 for t0 in np.arange(21.25, 22.6, 0.05) if not loc._wheel_locked(t0, t0 + 0.05)]
    assert ends and 21.26 + 2.39 / 3.0 - 0.05 <= ends[0] <= 21.26 + 2.7 / 3.0 + 0.05


def test_wheel_speed_noise_is_no_lock():
    """An encoder's noise (0.1 m/s at 100 Hz: 14 m/s^2 of apparent deceleration from one
    sample to the next) must not be taken for a lock, nor told as one: the drop is measured
    over a keyframe interval. Sample to sample, 0.03 m/s of noise made 3-6 told locks a
    minute."""
    rng = np.random.default_rng(3)
    loc = Localizer(LocalizerParams(), load_vehicle(), load_site())
    for i in range(6000):
        loc.add_vehicle_state(0.01 * i, 2.0 + rng.normal(0.0, 0.1), 0.0)
    assert not any(loc._wheel_locked(t0, t0 + 0.05) for t0 in np.arange(0.0, 59.9, 0.05))
    assert not loc.pop_events()


def test_calibration_every_few_keyframes_estimates_as_one_per_keyframe():
    """One calibration state every 5 keyframes (the default) against one per keyframe, on the
    same readings with the same calibration errors: the same track and calibration within
    what the drift makes of them, with fewer variables in the window."""
    kw = dict(seconds=60.0, speed_scale=1.05, handlebar_offset=0.03, gyro_bias=0.005)
    every = {n: run(params=dataclasses.replace(LocalizerParams(), calibration_every=n), **kw) for n in (1, 5)}
    (e1, loc1, est1), (e5, loc5, est5) = every[1], every[5]
    assert loc5.p.calibration_every == 5 and loc1.p.calibration_every == 1
    settled1, settled5 = e1[e1[:, 0] > 30.0], e5[e5[:, 0] > 30.0]
    assert abs(rmse(settled5[:, 1]) - rmse(settled1[:, 1])) < 0.02  # [m]
    for name in ("wheel_speed_scale", "handlebar_offset", "gyro_bias", "mag_hard_iron_x"):
        assert est5.calibration[name] == pytest.approx(est1.calibration[name], abs=0.01 * max(1.0, abs(est1.calibration[name])))
    # B, K, M every 5th keyframe: 2 + 3/5 variables a keyframe instead of 5
    n1, n5 = len(loc1.smoother.stamps), len(loc5.smoother.stamps)
    assert n5 < 0.65 * n1, (n5, n1)
