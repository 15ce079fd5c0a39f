"""Launch arguments that roslaunch itself could swallow: checked by loading the launch
files' configuration (no master, no nodes)."""
import pytest


def localization_params(argv):
    import roslaunch.config
    import rospkg

    path = rospkg.RosPack().get_path("quadrivio") + "/launch/sim.launch"
    cfg = roslaunch.config.load_config_default([(path, list(argv))], None, verbose=False)
    return {k: v.value for k, v in cfg.params.items() if k.startswith("/localization/")}


def test_sim_launch_loads_the_simulated_magnetometers_calibration_by_default():
    p = localization_params([])
    assert p["/localization/priors/magnetometer/source"].startswith("calibrate_mag")
    assert p["/localization/priors/magnetometer/hard_iron_sigma"] < 1.0


@pytest.mark.parametrize("value", ["none", "None", " none "])
def test_mag_calibration_none_means_uncalibrated(value):
    p = localization_params([f"mag_calibration:={value}"])
    assert p["/localization/priors/magnetometer/source"] == "uncalibrated"
    assert p["/localization/priors/magnetometer/hard_iron_sigma"] == 15.0


def test_an_empty_value_is_dropped_by_roslaunch():
    """Why 'none': roslaunch drops 'mag_calibration:=' (rosgraph.names.load_mappings keeps
    only non-empty values) and keeps the default, so 'empty means uncalibrated' could not
    work from a shell. If roslaunch ever passes it, empty means uncalibrated too (the
    launch file's test is for '' or 'none')."""
    p = localization_params(["mag_calibration:="])
    assert p["/localization/priors/magnetometer/source"].startswith("calibrate_mag")


def node_names(argv, launch="sim.launch"):
    import roslaunch.config
    import rospkg

    path = rospkg.RosPack().get_path("quadrivio") + "/launch/" + launch
    cfg = roslaunch.config.load_config_default([(path, list(argv))], None, verbose=False)
    return {n.name for n in cfg.nodes}


@pytest.mark.parametrize("launch", ["sim.launch", "real.launch"])
def test_excitation_replaces_navigation(launch):
    argv = [] if launch == "sim.launch" else ["plc_host:=10.0.0.2"]
    default = node_names(argv, launch)
    assert "follower" in default and "excitation" not in default
    exc = node_names(argv + ["excitation:=true"], launch)
    assert "excitation" in exc and not {"follower", "path_publisher", "planner"} & exc
    assert "localization" in exc and "plc_client" in exc
