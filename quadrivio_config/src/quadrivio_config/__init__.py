"""Typed, validated configuration: nested mappings (YAML files, ROS parameter trees)
turned into frozen dataclasses.

Every tunable of the stack is a field of a frozen dataclass declared with
:func:`param`, which carries its unit, allowed range or choices and a one-line
meaning. :func:`from_mapping` builds the dataclass from a mapping and refuses, with
a :class:`ConfigError` naming the source, the key and the value:

* a missing key that has no default,
* a key the dataclass does not know (a typo must not be silently ignored),
* a value of the wrong type (``"1.0"`` for a float, ``yes`` for a float, ...),
* a number outside its range, NaN, or a string outside its choices.

The module is ROS-free: nodes pass ``rospy.get_param("~")`` in, tools pass
:func:`load_yaml` in. Both get the same checks and the same messages.
"""

from __future__ import annotations

import dataclasses
import math
import os
import typing
from dataclasses import MISSING
from typing import Any, Dict, Mapping, Optional, Tuple, Type, TypeVar

import yaml

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file or parameter is missing, malformed or out of range."""


def param(default: Any = MISSING, *, lo: Optional[float] = None, hi: Optional[float] = None,
          lo_open: bool = False, hi_open: bool = False, unit: str = "",
          choices: Optional[Tuple[Any, ...]] = None, doc: str = "") -> Any:
    """Declare a dataclass field with validation metadata.

    ``lo``/``hi`` bound numbers (inclusive unless ``lo_open``/``hi_open``); ``choices``
    restricts strings; ``unit`` and ``doc`` appear in error messages and generated docs.
    Mutable defaults (lists, dicts) are copied per instance.
    """
    meta = dict(lo=lo, hi=hi, lo_open=lo_open, hi_open=hi_open, unit=unit, choices=choices, doc=doc)
    if isinstance(default, (list, dict)):
        value = default
        return dataclasses.field(default_factory=lambda: type(value)(value), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def _describe(key: str, source: str) -> str:
    return f"{source}: '{key}'" if source else f"'{key}'"


def _check_number(value: Any, key: str, source: str, meta: Mapping[str, Any], kind: type) -> Any:
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ConfigError(f"{_describe(key, source)} = {value!r} must be a number"
                          f"{' in ' + meta['unit'] if meta.get('unit') else ''}")
    if kind is int:
        if isinstance(value, float) and not value.is_integer():
            raise ConfigError(f"{_describe(key, source)} = {value!r} must be an integer")
        value = int(value)
    else:
        value = float(value)
        if math.isnan(value):
            raise ConfigError(f"{_describe(key, source)} is NaN")
    lo, hi = meta.get("lo"), meta.get("hi")
    too_low = lo is not None and (value <= lo if meta.get("lo_open") else value < lo)
    too_high = hi is not None and (value >= hi if meta.get("hi_open") else value > hi)
    if too_low or too_high:
        left = "(" if meta.get("lo_open") else "["
        right = ")" if meta.get("hi_open") else "]"
        rng = f"{left}{lo if lo is not None else '-inf'}, {hi if hi is not None else 'inf'}{right}"
        unit = f" {meta['unit']}" if meta.get("unit") else ""
        raise ConfigError(f"{_describe(key, source)} = {value!r} is outside the allowed range {rng}{unit}")
    return value


def _convert(value: Any, tp: Any, key: str, source: str, meta: Mapping[str, Any]) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if origin is typing.Union:  # Optional[X]
        if value is None and type(None) in args:
            return None
        inner = [a for a in args if a is not type(None)]
        return _convert(value, inner[0], key, source, meta)
    if dataclasses.is_dataclass(tp):
        return from_mapping(tp, value, source, key)
    if tp is float or tp is int:
        return _check_number(value, key, source, meta, tp)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{_describe(key, source)} = {value!r} must be true or false")
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{_describe(key, source)} = {value!r} must be a string")
        choices = meta.get("choices")
        if choices and value not in choices:
            raise ConfigError(f"{_describe(key, source)} = {value!r} is not one of {', '.join(map(str, choices))}")
        return value
    if origin in (tuple, typing.Tuple):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{_describe(key, source)} = {value!r} must be a list")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{key}[{i}]", source, meta) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{_describe(key, source)} = {value!r} must have {len(args)} elements")
        return tuple(_convert(v, a, f"{key}[{i}]", source, meta) for i, (v, a) in enumerate(zip(value, args)))
    if origin in (dict, typing.Dict):
        if not isinstance(value, Mapping):
            raise ConfigError(f"{_describe(key, source)} = {value!r} must be a mapping")
        return {str(k): _convert(v, args[1], f"{key}.{k}", source, meta) for k, v in value.items()}
    if tp is Any:
        return value
    raise TypeError(f"config field type {tp!r} of '{key}' is not supported")


def from_mapping(cls: Type[T], data: Any, source: str = "", prefix: str = "") -> T:
    """Build the frozen dataclass ``cls`` from ``data``, validating every field.

    ``source`` names where the data came from (a file path or a ROS namespace) and
    ``prefix`` the dotted key of ``data`` inside it; both end up in error messages.
    """
    where = prefix or "(top level)"
    if data is None:
        data = {}
    if not isinstance(data, Mapping):
        raise ConfigError(f"{_describe(where, source)} must be a mapping of keys to values, got {data!r}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(map(str, data)) - known)
    if unknown:
        raise ConfigError(f"{_describe(where, source)} has unknown key(s) {', '.join(unknown)}; "
                          f"known keys: {', '.join(sorted(known))}")
    kwargs: Dict[str, Any] = {}
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        key = f"{prefix}.{f.name}" if prefix else f.name
        if f.name in data:
            kwargs[f.name] = _convert(data[f.name], hints[f.name], key, source, f.metadata)
        elif f.default is MISSING and f.default_factory is MISSING:  # type: ignore[misc]
            if dataclasses.is_dataclass(hints[f.name]):
                kwargs[f.name] = from_mapping(hints[f.name], {}, source, key)
            else:
                unit = f" [{f.metadata['unit']}]" if f.metadata.get("unit") else ""
                raise ConfigError(f"{_describe(key, source)} is missing{unit}: {f.metadata.get('doc', '')}".rstrip(": "))
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (ValueError, TypeError) as exc:  # cross-field checks in __post_init__
        raise ConfigError(f"{source or cls.__name__}: {exc}") from exc


def to_mapping(obj: Any) -> Any:
    """The inverse of :func:`from_mapping`: plain dicts, lists and scalars (for YAML)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_mapping(getattr(obj, f.name)) for f in dataclasses.fields(obj) if f.init}
    if isinstance(obj, (list, tuple)):
        return [to_mapping(v) for v in obj]
    if isinstance(obj, dict):
        return {k: to_mapping(v) for k, v in obj.items()}
    return obj


# libyaml's safe loader where PyYAML was built with it (Debian's is): the same data from every
# config and scenario file, eight times faster than the pure-Python one (a closed-loop run
# reads 19 files)
_SAFE_LOADER = getattr(yaml, "CSafeLoader", yaml.SafeLoader)


def load_yaml(path: str) -> Dict[str, Any]:
    """Read a YAML mapping, failing with a message that names the file."""
    if not path:
        raise ConfigError("no YAML file given (empty path)")
    if not os.path.isfile(path):
        raise ConfigError(f"{path}: file not found")
    try:
        with open(path, "r", encoding="utf-8") as fh:
            data = yaml.load(fh, Loader=_SAFE_LOADER)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{path}: malformed YAML: {exc}") from exc
    except OSError as exc:
        raise ConfigError(f"{path}: cannot read: {exc}") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the top level must be a mapping of keys to values, got {type(data).__name__}")
    return data


def load_dataclass(cls: Type[T], path: str, section: Optional[str] = None) -> T:
    """Load ``cls`` from a YAML file, optionally from one top-level ``section`` of it."""
    data = load_yaml(path)
    if section is not None:
        if section not in data:
            raise ConfigError(f"{path}: has no top-level '{section}' section")
        return from_mapping(cls, data[section], path, section)
    return from_mapping(cls, data, path)


def replace_nested(obj: T, changes: Mapping[str, Any], source: str = "overrides") -> T:
    """A copy of dataclass ``obj`` with ``changes`` (a nested mapping) applied and validated.

    Used for scenario overrides: ``{"gps": {"noise_std": 0.5}}`` changes one key and
    keeps the rest, with the same checks as a full load.
    """
    merged = _merge(to_mapping(obj), changes)
    return from_mapping(type(obj), merged, source)


def _merge(base: Any, changes: Any) -> Any:
    if isinstance(base, dict) and isinstance(changes, Mapping):
        out = dict(base)
        for k, v in changes.items():
            out[k] = _merge(base[k], v) if k in base else v
        return out
    return changes
