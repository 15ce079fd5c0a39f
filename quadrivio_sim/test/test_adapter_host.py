"""The adapter host's parameters (quadrivio_sim.ros.adapters.hosted_slots): which adapters
one process runs, under which names, and a clear error for each way the list can be wrong."""
import numpy as np
import pytest

from quadrivio_sim.noise import adapter_rng
from quadrivio_sim.ros.adapters import hosted_slots

LIST = [{"name": "imu_adapter", "type": "imu"}, {"name": "laser_front", "type": "laser"},
        {"name": "laser_rear", "type": "laser"}]


def test_each_adapter_is_named_in_the_hosts_namespace_with_its_topics_under_its_name():
    slots = hosted_slots({"adapters": LIST, "imu_adapter": {"rate": 200.0}, "laser_rear": {"frame_id": "r"}}, "/car/")
    assert [k for k, _ in slots] == ["imu", "laser", "laser"]
    imu, front, rear = (s for _, s in slots)
    assert (imu.name, imu.short, imu.prefix, imu.data) == ("/car/imu_adapter", "imu_adapter", "imu_adapter/",
                                                            {"rate": 200.0})
    assert front.data == {} and rear.data == {"frame_id": "r"}
    assert front.topic("scan_in") == "laser_front/scan_in"


def test_a_hosted_adapter_draws_the_stream_it_would_draw_as_its_own_node():
    """The stream id is the adapter's resolved name: /imu_adapter hosted in the root
    namespace draws what the node /imu_adapter drew, and the two lasers differ."""
    (_, imu), (_, front), (_, rear) = hosted_slots({"adapters": LIST}, "/")
    assert imu.name == "/imu_adapter"
    draws = {s.name: adapter_rng(7, s.name).normal(size=4) for s in (imu, front, rear)}
    np.testing.assert_array_equal(draws["/imu_adapter"], np.random.default_rng(
        [7, __import__("zlib").crc32(b"/imu_adapter")]).normal(size=4))
    assert not np.allclose(draws["/laser_front"], draws["/laser_rear"])


@pytest.mark.parametrize("params, words", [
    ({}, "~adapters must be a non-empty list"),
    ({"adapters": []}, "~adapters must be a non-empty list"),
    ({"adapters": "imu_adapter"}, "~adapters must be a non-empty list"),
    ({"adapters": ["imu_adapter"]}, "~adapters[0] = 'imu_adapter'"),
    ({"adapters": [{"name": "a", "type": "imu", "rate": 1}]}, "~adapters[0]"),
    ({"adapters": [{"name": "a", "type": "lidar"}]}, "unknown type 'lidar' (one of camera, gps, imu, laser, mag)"),
    ({"adapters": [{"name": "a", "type": "imu"}, {"name": "a", "type": "mag"}]}, "~adapters[1]: name 'a'"),
    ({"adapters": [{"name": "a/b", "type": "imu"}]}, "~adapters[0]: name 'a/b'"),
    ({"adapters": [{"name": "a", "type": "imu"}], "a": 3}, "~a must be a dictionary of imu adapter parameters"),
    ({"adapters": [{"name": "a", "type": "imu"}], "imu_adaptr": {"rate": 1}}, "parameters for no listed adapter: ~imu_adaptr"),
])
def test_a_wrong_list_is_refused_naming_what_is_wrong(params, words):
    with pytest.raises(ValueError) as err:
        hosted_slots(params, "/")
    assert words in str(err.value)
