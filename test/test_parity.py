"""quadrivio.parity.compare: every kind of difference between two runs' topics is named."""
import copy
import math

from quadrivio import parity


def _profile():
    return {"/imu/data": {"type": "sensor_msgs/Imu", "frames": {"imu_link"}, "children": set(), "rate": 100.0,
                          "covariance": {"orientation_covariance": "unknown",
                                         "angular_velocity_covariance": "*000*000*"}, "messages": 5000},
            "/tf_static": {"type": "tf2_msgs/TFMessage", "frames": {"base_link"}, "children": {"gps_link"},
                           "rate": math.nan, "covariance": {}, "messages": 1}}


def test_the_same_profile_has_no_difference():
    assert parity.compare(_profile(), _profile()) == []
    b = _profile()
    b["/imu/data"]["rate"] = 100.0 * (1 - 0.8 * parity.RATE_TOLERANCE)
    assert parity.compare(_profile(), b) == []


def test_every_difference_is_named():
    cases = [
        (lambda p: p.pop("/imu/data"), "/imu/data: only in sim.launch"),
        (lambda p: p["/imu/data"].update(type="sensor_msgs/MagneticField"), "type"),
        (lambda p: p["/imu/data"].update(frames={"imu"}), "frames"),
        (lambda p: p["/tf_static"].update(children={"gps"}), "children"),
        (lambda p: p["/imu/data"].update(rate=90.0), "100.00 Hz vs 90.00 Hz"),
        (lambda p: p["/imu/data"].update(rate=math.nan), "Hz"),
        (lambda p: p["/imu/data"]["covariance"].update(orientation_covariance="*000*000*"), "covariance"),
    ]
    for change, words in cases:
        b = copy.deepcopy(_profile())
        change(b)
        problems = parity.compare(_profile(), b)
        assert len(problems) == 1 and words in problems[0], (words, problems)


def test_covariance_structure_not_values():
    assert parity.pattern([-1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]) == "unknown"
    assert parity.pattern([0.2, -0.01, 0.0, -0.01, 0.3, 0.0, 0.0, 0.0, 5.0]) == "**0**000*"
    assert parity.pattern([0.2, 0.01, 0.0, 0.01, 0.3, 0.0, 0.0, 0.0, 5.0]) == "**0**000*"
