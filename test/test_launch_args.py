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


@pytest.mark.parametrize("launch,argv", [("sim.launch", ["scenario:=consumer", "seed:=4"]),
                                         ("sim.launch", ["scenario:=rtk"]), ("real.launch", ["scenario:=rtk"])])
def test_a_launch_sets_the_scenario_and_seed_fresh(launch, argv):
    """On a master that outlives a launch, an earlier run's scenario keys (the figure eight's
    outages read by a noise run) or seed must not stay: /scenario and /run are cleared
    before the launch's parameters are set (roslaunch's clear_params)."""
    import roslaunch.config
    import rospkg

    path = rospkg.RosPack().get_path("quadrivio") + "/launch/" + launch
    cfg = roslaunch.config.load_config_default([(path, argv)], None, verbose=False)
    assert {"/scenario/", "/run/"} <= set(cfg.clear_params)
    params = {k: v.value for k, v in cfg.params.items()}
    name = argv[0].split(":=")[1]
    assert params["/scenario/name"] == name and params["/scenario/source"].endswith(f"/{name}.yaml")
    assert params.get("/run/seed") == (4 if "seed:=4" in argv else None)


@pytest.mark.parametrize("launch", ["sim.launch", "real.launch"])
def test_scenario_takes_a_path_to_a_yaml_as_experiment_does(launch, tmp_path):
    """``scenario:=/some/where/mine.yaml`` loads that file (it looked for
    scenarios//some/where/mine.yaml.yaml); a name still comes from scenarios/."""
    import roslaunch.config
    import rospkg
    import yaml

    mine = tmp_path / "mine.yaml"
    mine.write_text(yaml.safe_dump({"name": "mine", "seed": 3}))
    path = rospkg.RosPack().get_path("quadrivio") + "/launch/" + launch
    for arg, name, source in ((str(mine), "mine", str(mine)), ("orchard", "orchard", "/scenarios/orchard.yaml")):
        cfg = roslaunch.config.load_config_default([(path, [f"scenario:={arg}"])], None, verbose=False)
        params = {k: v.value for k, v in cfg.params.items()}
        assert params["/scenario/name"] == name and params["/scenario/source"].endswith(source)


def test_a_scenarios_vehicle_reaches_the_nodes_and_the_urdf(tmp_path):
    """sim.launch scenario_file:=F with a vehicle: section: the overrides are on
    /scenario/vehicle (read over /vehicle by every node, the predictor included) and in
    robot_description; vehicle_file:= chooses the base file."""
    import roslaunch.config
    import rospkg
    import yaml

    base = rospkg.RosPack().get_path("quadrivio_description") + "/config/vehicle.yaml"
    with open(base) as f:
        data = yaml.safe_load(f)
    data["wheelbase"] = 1.3
    vfile = tmp_path / "my_atv.yaml"
    vfile.write_text(yaml.safe_dump(data))
    scenario = tmp_path / "heavy.yaml"
    scenario.write_text("name: heavy\nvehicle: {body: {mass: 452.5}, drivetrain: {drive: 4wd}}\n")
    path = rospkg.RosPack().get_path("quadrivio") + "/launch/sim.launch"
    cfg = roslaunch.config.load_config_default(
        [(path, [f"scenario_file:={scenario}", f"vehicle_file:={vfile}"])], None, verbose=False)
    params = {k: v.value for k, v in cfg.params.items()}
    assert params["/scenario/vehicle/drivetrain/drive"] == "4wd" and params["/scenario/vehicle/body/mass"] == 452.5
    assert params["/vehicle/wheelbase"] == 1.3 and params["/vehicle/drivetrain/drive"] == "2wd"
    from quadrivio_description.urdf import build_urdf
    from quadrivio_description.vehicle import load_vehicle, with_overrides

    urdf = params["/robot_description"]
    expected = with_overrides(load_vehicle(str(vfile)), {"body": {"mass": 452.5}, "drivetrain": {"drive": "4wd"}}, "t")
    assert urdf == build_urdf(expected, root_inertia=False)
    plain = roslaunch.config.load_config_default([(path, [])], None, verbose=False)
    assert plain.params["/robot_description"].value != urdf


def test_the_stand_in_and_real_launch_share_no_node():
    """sim.launch hardware:=true runs only what stands in for the vehicle; real.launch on the
    same master adds the stack, the NMEA driver and the description: no name twice (roslaunch
    would kill the first), and use_sim_time from real.launch's argument."""
    import roslaunch.config
    import rospkg

    d = rospkg.RosPack().get_path("quadrivio") + "/launch/"
    stand_in = roslaunch.config.load_config_default([(d + "sim.launch", ["hardware:=true"])], None, verbose=False)
    names = {n.namespace + n.name for n in stand_in.nodes}
    assert names == {"/simulator", "/sensor_adapters"}
    assert stand_in.params["/sensor_adapters/gps_adapter/publish_fix"].value is False  # NMEA only: the driver publishes
    real = roslaunch.config.load_config_default(
        [(d + "real.launch", ["use_sim_time:=true", "plc_host:=127.0.0.1", "gps_device:=/tmp/x"])], None, verbose=False)
    assert not names & {n.namespace + n.name for n in real.nodes}
    assert real.params["/use_sim_time"].value is True
    assert {"/localization", "/follower", "/plc_client", "/gps/nmea_gps"} <= {n.namespace + n.name for n in real.nodes}


@pytest.mark.parametrize("launch", ["sim.launch", "real.launch"])
def test_the_guard_is_the_roscpp_node_and_guard_arg_picks_the_python_reference(launch):
    import roslaunch.config
    import rospkg

    path = rospkg.RosPack().get_path("quadrivio") + "/launch/" + launch
    extra = ["plc_host:=127.0.0.1"] if launch == "real.launch" else []

    def guard_type(argv):
        cfg = roslaunch.config.load_config_default([(path, extra + argv)], None, verbose=False)
        (node,) = [n for n in cfg.nodes if n.name == "guard"]
        return node.package, node.type

    assert guard_type([]) == ("quadrivio_navigation", "guard_cpp")
    assert guard_type(["guard:=guard"]) == ("quadrivio_navigation", "guard")
