"""Reading parameters once, at start-up, into validated dataclasses.

A node calls :func:`node_params` (its private ``~`` namespace) and :func:`vehicle_params`
(the ``/vehicle`` namespace loaded from ``vehicle.yaml`` by the launch files) before
creating any publisher. A missing, unknown or out-of-range parameter stops the node
right there with one ``FATAL`` line naming the key, the value and the allowed range.
"""

from __future__ import annotations

import sys
from typing import Any, Dict, NoReturn, Tuple, Type, TypeVar

from . import compat

compat.checked()  # rospy's version checked and the mends applied before rospy's use

import rospy

from quadrivio_config import ConfigError, from_mapping, replace_nested
from quadrivio_description.site import SiteParams, default_site_file, load_site
from quadrivio_description.vehicle import VehicleParams, default_vehicle_file, load_vehicle, with_overrides

T = TypeVar("T")


def fatal(message: str) -> NoReturn:
    """Log ``message`` as FATAL and stop the node with exit status 1."""
    rospy.logfatal(message)
    sys.stderr.flush()
    raise SystemExit(1)


def private_params() -> Dict[str, Any]:
    """The node's private parameters, less ``~lockstep`` (every node's: see ros/lockstep.py)."""
    params = rospy.get_param("~", {})
    return {k: v for k, v in params.items() if k != "lockstep"} if isinstance(params, dict) else {}


def node_params(cls: Type[T], data: Dict[str, Any] = None, source: str = "") -> T:
    """The node's private parameters as ``cls``; stops the node on a bad value."""
    data = private_params() if data is None else data
    try:
        return from_mapping(cls, data, source or rospy.get_name())
    except ConfigError as exc:
        fatal(f"bad parameter: {exc}")


def split_params(data: Dict[str, Any], cls: Type[Any]) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """Split a parameter dict into the keys that are fields of ``cls`` and the rest."""
    import dataclasses

    names = {f.name for f in dataclasses.fields(cls)}
    mine = {k: v for k, v in data.items() if k in names}
    rest = {k: v for k, v in data.items() if k not in names}
    return mine, rest


def vehicle_params() -> VehicleParams:
    """Vehicle parameters from ``/vehicle`` (or, when absent, the package's vehicle.yaml),
    with the scenario's ``vehicle:`` overrides (``/scenario/vehicle``) applied."""
    try:
        if rospy.has_param("/vehicle"):
            vehicle = from_mapping(VehicleParams, rospy.get_param("/vehicle"), "/vehicle")
        else:
            rospy.loginfo("no /vehicle parameters on the server: loading %s", default_vehicle_file())
            vehicle = load_vehicle()
        if rospy.has_param("/scenario/vehicle"):
            vehicle = with_overrides(vehicle, rospy.get_param("/scenario/vehicle"), "/scenario/vehicle")
        return vehicle
    except ConfigError as exc:
        fatal(f"bad vehicle parameter: {exc}")


def site_params() -> SiteParams:
    """Site parameters (datum, magnetic field) from ``/site`` (or the package's site.yaml)."""
    try:
        if rospy.has_param("/site"):
            return from_mapping(SiteParams, rospy.get_param("/site"), "/site")
        rospy.loginfo("no /site parameters on the server: loading %s", default_site_file())
        return load_site()
    except ConfigError as exc:
        fatal(f"bad site parameter: {exc}")


def with_scenario(params: T, section: str) -> T:
    """``params`` with the running scenario's overrides for ``section`` applied.

    A scenario file is loaded into ``/scenario`` by the launch files; its
    ``/scenario/<section>`` (e.g. ``sensors/gps``) overrides keys of this node's
    parameters, with the same validation as the node's own parameters.
    """
    key = "/scenario/" + section.strip("/")
    if not rospy.has_param(key):
        return params
    try:
        return replace_nested(params, rospy.get_param(key), key)
    except ConfigError as exc:
        fatal(f"bad scenario parameter: {exc}")


def run_seed() -> int:
    """The run's seed: ``/run/seed`` (launch argument) or the scenario's ``/scenario/seed``, else 0."""
    for key in ("/run/seed", "/scenario/seed"):
        if rospy.has_param(key):
            value = rospy.get_param(key)
            if isinstance(value, bool) or not isinstance(value, int) or value < 0:
                fatal(f"bad parameter: {key} = {value!r} must be a non-negative integer")
            return value
    return 0
