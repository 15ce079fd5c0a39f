"""Vehicle parameters: derived quantities and clear errors on bad files and values."""
import math
import os

import pytest
import yaml

from quadrivio_config import ConfigError, from_mapping, load_yaml, replace_nested, to_mapping
from quadrivio_description.vehicle import VehicleParams, default_vehicle_file, load_vehicle


@pytest.fixture(scope="module")
def vehicle():
    return load_vehicle()


def test_paper_dimensions(vehicle):
    # Tables 1 and 2 of the paper.
    assert vehicle.body.length == pytest.approx(2.065)
    assert vehicle.body.width == pytest.approx(1.180)
    assert vehicle.body.height == pytest.approx(1.240)
    assert vehicle.body.mass == pytest.approx(390.0)
    assert vehicle.wheelbase == pytest.approx(1.250)
    assert vehicle.wheels.diameter == pytest.approx(0.635)
    assert vehicle.wheels.front_width == pytest.approx(0.201)
    assert vehicle.wheels.rear_width == pytest.approx(0.247)


def test_track_derived_from_width_and_tyres(vehicle):
    # Table 2's 1920 mm track cannot fit a 1.18 m wide vehicle: outer tyre faces at the width.
    assert vehicle.front_track == pytest.approx(1.180 - 0.201)
    assert vehicle.rear_track == pytest.approx(1.180 - 0.247)
    assert vehicle.front_track + vehicle.wheels.front_width <= vehicle.body.width + 1e-12
    assert vehicle.rear_track + vehicle.wheels.rear_width <= vehicle.body.width + 1e-12


def test_derived_quantities(vehicle):
    assert vehicle.wheel_radius == pytest.approx(0.3175)
    assert vehicle.chassis_mass == pytest.approx(390.0 - 4 * (11.0 + 4.0))
    assert vehicle.min_turning_radius == pytest.approx(1.25 / math.tan(0.42))
    # Corner loads share the sprung weight by the lever rule.
    total = 2 * vehicle.corner_static_load(True) + 2 * vehicle.corner_static_load(False)
    assert total == pytest.approx(vehicle.chassis_mass * 9.81)
    assert vehicle.corner_static_load(True) / vehicle.corner_static_load(False) == pytest.approx(
        vehicle.body.com_x / (vehicle.wheelbase - vehicle.body.com_x))
    assert 0.7 < vehicle.static_stability_factor < 1.2


def _raw():
    return load_yaml(default_vehicle_file())


@pytest.mark.parametrize("path,value,needle", [
    (("wheelbase",), -1.0, "'wheelbase' = -1.0 is outside"),
    (("body", "mass"), float("nan"), "'body.mass' is NaN"),
    (("suspension", "front", "stiffness"), "stiff", "'suspension.front.stiffness' = 'stiff' must be a number"),
    (("drivetrain", "drive"), "6wd", "'drivetrain.drive' = '6wd' is not one of 2wd, 4wd"),
    (("steering", "max_angle"), True, "'steering.max_angle' = True must be a number"),
])
def test_bad_values_name_key_and_value(path, value, needle):
    raw = _raw()
    node = raw
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ConfigError) as err:
        from_mapping(VehicleParams, raw, "vehicle.yaml")
    assert needle in str(err.value)
    assert str(err.value).startswith("vehicle.yaml")


def test_unknown_and_missing_keys():
    raw = _raw()
    raw["body"]["lenght"] = 2.0
    with pytest.raises(ConfigError, match="unknown key.*lenght"):
        from_mapping(VehicleParams, raw, "vehicle.yaml")
    raw = _raw()
    del raw["wheels"]["diameter"]
    with pytest.raises(ConfigError, match="'wheels.diameter' is missing"):
        from_mapping(VehicleParams, raw, "vehicle.yaml")
    raw = _raw()
    del raw["sensors"]["imu_link"]
    with pytest.raises(ConfigError, match="imu_link"):
        from_mapping(VehicleParams, raw, "vehicle.yaml")


def test_cross_field_checks():
    raw = _raw()
    raw["body"]["com_x"] = 2.0  # behind the front axle
    with pytest.raises(ConfigError, match="com_x"):
        from_mapping(VehicleParams, raw, "vehicle.yaml")
    raw = _raw()
    raw["body"]["width"] = 0.4  # no room for the tyres
    raw["wheels"]["front_width"] = 0.5
    with pytest.raises(ConfigError, match="track"):
        from_mapping(VehicleParams, raw, "vehicle.yaml")


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="nope.yaml: file not found"):
        load_vehicle(str(tmp_path / "nope.yaml"))
    bad = tmp_path / "bad.yaml"
    bad.write_text("body: {length: 2.0\n  width: [")
    with pytest.raises(ConfigError, match="bad.yaml: malformed YAML"):
        load_vehicle(str(bad))
    listy = tmp_path / "list.yaml"
    listy.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match="list.yaml: the top level must be a mapping"):
        load_vehicle(str(listy))


def test_round_trip_and_overrides(vehicle, tmp_path):
    out = tmp_path / "v.yaml"
    out.write_text(yaml.safe_dump(to_mapping(vehicle)))
    assert load_vehicle(str(out)) == vehicle
    changed = replace_nested(vehicle, {"drivetrain": {"drive": "4wd"}})
    assert changed.drivetrain.drive == "4wd"
    assert changed.wheelbase == vehicle.wheelbase
    with pytest.raises(ConfigError, match="drivetrain.max_speed"):
        replace_nested(vehicle, {"drivetrain": {"max_speed": -3}})


def test_every_key_in_yaml_is_commented():
    # "config/*.yaml: every tunable, each key commented with meaning and unit."
    with open(default_vehicle_file()) as fh:
        lines = fh.read().splitlines()
    for line in lines:
        s = line.strip()
        if not s or s.startswith("#") or s.startswith("- "):
            continue
        key, _, value = s.partition(":")
        if value.strip() and not value.strip().startswith("{"):
            assert "#" in value or key in ("name", "xyz", "rpy"), f"uncommented key in vehicle.yaml: {line}"
    assert os.path.basename(default_vehicle_file()) == "vehicle.yaml"
