"""The wheel-slip detection in the whole offline run (quadrivio.offline: the simulator core,
the sensor models and the smoother): the stuck_wall scenario. The detector's own cases are
quadrivio_localization/test/test_wheel_slip.py."""
import numpy as np


def test_stuck_against_a_wall_the_estimate_holds():
    """The scenario stuck_wall offline (no guard: the follower pushes on): before the slip
    detection the estimate drove on through the wall at the wheels' speed to 30 m from the
    truth. Now it stays with the truth, within 0.5 m plus the receiver's own drift (which no
    estimator without odometry can tell from the position), and the slip is named in the
    faults within 1 s of the wheels spinning up."""
    from quadrivio import offline
    from quadrivio.scenario import load_scenario

    s = load_scenario("stuck_wall")
    r = offline.run(s, 1)
    tr, est, ant = r.truth, r.estimate, r.antenna
    stuck_at = tr[np.argmax((tr[:, 1] > 11.0) & (np.abs(tr[:, 4]) < 0.05)), 0]
    assert 8.0 < stuck_at < 12.0
    after = est[est[:, 0] > stuck_at]
    drift = np.hypot(np.interp(after[:, 0], ant[:, 0], ant[:, 9]), np.interp(after[:, 0], ant[:, 0], ant[:, 10]))
    err = np.hypot(np.interp(after[:, 0], tr[:, 0], tr[:, 1]) - after[:, 1],
                   np.interp(after[:, 0], tr[:, 0], tr[:, 2]) - after[:, 2])
    assert np.all(err <= 0.5 + drift), f"error {err.max():.2f} m (drift {drift[np.argmax(err)]:.2f} m)"
    assert float(tr[-1, 1]) < 12.2  # the vehicle did stay at the wall for the rest of the run
    assert r.counters["intervals_wheel_slip"] > 20 * 15  # 15 s and more of the 30 s against it
    named = [t for t, text in r.diagnostics if "wheels slip" in text]
    assert named, r.diagnostics
    assert r.counters["gps_not_used"].get("multipath", 0) < 10  # the fixes were believed
