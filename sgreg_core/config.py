"""Typed configs: every component has one dataclass whose defaults are the only source of its
settings. From plain dicts (YAML / JSON) and back, dotted overrides, and `param` fields, which
the ROS nodes declare as parameters (sgreg_ros/params.py) with the default, description and
valid range written here once.

Public API:
    param(default, help, low=None, high=None, choices=(), factory=None, live=False) -> dataclasses.Field
    node_params(cls) -> {field name: (default, help, low, high, choices, live)}
    from_dict(cls, data) / to_dict(cfg) / apply_overrides(data, ["a.b=1", ...])
        from_dict checks each value against the field's type (numbers, strings, tuples,
        optionals) and a `param` field's range or choices, naming the field
"""
from __future__ import annotations

import dataclasses
import math
import types
import typing
from collections.abc import Callable, Mapping

PARAM = "node_param"   # the field metadata key


def param(default=dataclasses.MISSING, help: str = "", low: float | None = None,
          high: float | None = None, choices: tuple = (),
          factory: Callable | None = None, live: bool = False) -> dataclasses.Field:
    """A dataclass field that the nodes also expose as a ROS parameter of the same name: its
    default, a one-line description, and its valid range (numbers) or choices (strings).
    live: the component reads the field at each use, so a node may change it at run time
    (`ros2 param set`); every other parameter is read-only once the node runs."""
    meta = {PARAM: (help, low, high, tuple(choices), live)}
    if factory is not None:
        return dataclasses.field(default_factory=factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def node_params(cls) -> dict[str, tuple]:
    """{name: (default, help, low, high, choices, live)} of the `param` fields of dataclass `cls`."""
    out = {}
    for f in dataclasses.fields(cls):
        if PARAM in f.metadata:
            default = f.default_factory() if f.default is dataclasses.MISSING else f.default
            out[f.name] = (default, *f.metadata[PARAM])
    return out


def from_dict(cls, data: Mapping | None):
    """Build dataclass `cls` from a (partial) dict; missing keys keep their defaults, unknown
    keys are an error naming the class."""
    data = data or {}
    hints = typing.get_type_hints(cls)
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = set(data) - names
    if unknown:
        raise ValueError(f"{cls.__name__}: unknown keys {sorted(unknown)}")
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kwargs = {}
    for key, value in data.items():
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, Mapping):
                raise ValueError(f"{cls.__name__}.{key} is a section ({hint.__name__}), "
                                 f"got {value!r}")
            value = from_dict(hint, value)
        else:
            if not _fits(value, hint):
                raise ValueError(f"{cls.__name__}.{key} must be {_name(hint)}, got {value!r}")
            _check_range(cls, fields[key], value)
            if typing.get_origin(hint) is tuple:
                value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


def _fits(value, hint) -> bool:
    """Whether a value read from YAML / JSON / an override is of the field's type: an int
    where a float is asked is taken, a bool for a number is not, NaN never (no setting means
    "undefined"). Hints other than numbers, strings, tuples and optionals are not checked."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(value, a) for a in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and not math.isnan(value)
    if hint is str:
        return isinstance(value, str)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            return False
        if len(args) == 2 and args[1] is Ellipsis:
            return all(_fits(v, args[0]) for v in value)
        return len(args) == len(value) and all(_fits(v, a) for v, a in zip(value, args))
    return True


def _name(hint) -> str:
    return str(hint).replace("typing.", "") if typing.get_args(hint) else hint.__name__


def _check_range(cls, f: dataclasses.Field, value) -> None:
    """A `param` field's number must lie in its declared range, its string among its choices
    (the nodes refuse the same values as ROS parameters)."""
    if PARAM not in f.metadata:
        return
    _, low, high, choices, _ = f.metadata[PARAM]
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if number and ((low is not None and value < low) or (high is not None and value > high)):
        raise ValueError(f"{cls.__name__}.{f.name} must lie in [{low}, {high}], got {value!r}")
    if choices and isinstance(value, str) and value not in choices:
        raise ValueError(f"{cls.__name__}.{f.name} must be one of {list(choices)}, got {value!r}")


def to_dict(cfg) -> dict:
    """Plain dict (tuples become lists) that YAML and JSON both write."""
    def plain(v):
        if isinstance(v, dict):
            return {k: plain(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        return v
    return plain(dataclasses.asdict(cfg))


def apply_overrides(data: dict, overrides: list[str]) -> dict:
    """Apply "dotted.key=value" overrides (value parsed as YAML) to a nested dict, in place."""
    import yaml

    for item in overrides:
        key, sep, raw = item.partition("=")
        if not sep or not key:
            raise ValueError(f"override {item!r} is not KEY=VALUE")
        *parents, leaf = key.split(".")
        node = data
        for name in parents:
            node = node.setdefault(name, {})
            if not isinstance(node, dict):
                raise ValueError(f"override {item!r}: {name} is not a section")
        try:
            node[leaf] = yaml.safe_load(raw)
        except yaml.YAMLError as exc:
            reason = " ".join(str(exc).split())
            raise ValueError(f"override {item!r}: the value is not YAML ({reason})") from None
    return data
