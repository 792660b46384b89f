"""Typed configs: every component has one dataclass whose defaults are the only source of its
settings. From plain dicts (YAML / JSON) and back, dotted overrides, and `param` fields, which
the ROS nodes declare as parameters (sgreg_ros/params.py) with the default, description and
valid range written here once.

Public API:
    param(default, help, low=None, high=None, choices=(), factory=None, live=False) -> dataclasses.Field
    node_params(cls) -> {field name: (default, help, low, high, choices, live)}
    from_dict(cls, data) / to_dict(cfg) / apply_overrides(data, ["a.b=1", ...])
        from_dict checks each value against its field's type (NaN never) and a `param`
        field's range or choices, naming the field
    as_hinted(hint, value) -> value          a whole number for a float field as that float,
                                            a list for a tuple field as that tuple
    finite_number(x) -> bool                 a real number, not a bool, finite
    range_problem(value, low, high, choices) -> str | None   outside a `param` field's range
    check_types(cls, data, where) -> None   ValueError naming the first key of a (partial) dict
                                            that is not a field of cls or whose value does not
                                            fit the field's type (sections checked in turn)
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
    _check_keys(cls, data, cls.__name__)
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
            # infinity is a setting some configs take (a gate that never closes); NaN none
            if not _fits(hint, value, finite=False):
                raise ValueError(f"{cls.__name__}.{key} must be {_describe(hint, finite=False)}, "
                                 f"got {value!r}")
            _check_range(cls, fields[key], value)
            try:
                value = as_hinted(hint, value)
            except ValueError as exc:
                raise ValueError(f"{cls.__name__}.{key} {exc}") from None
        kwargs[key] = value
    return cls(**kwargs)


def range_problem(value, low: float | None, high: float | None, choices: tuple) -> str | None:
    """Why `value` is outside a `param` field's declared range (a number; NaN never inside) or
    its choices, else None: one rule for configs (from_dict) and the nodes' parameters."""
    number = isinstance(value, (int, float)) and not isinstance(value, bool)
    if number and not ((low is None or value >= low) and (high is None or value <= high)):
        return f"must lie in [{low}, {high}]"
    if choices and value not in choices:
        return f"must be one of {list(choices)}"
    return None


def _check_range(cls, f: dataclasses.Field, value) -> None:
    """A `param` field's value must lie in its declared range or among its choices (the nodes
    refuse the same values as ROS parameters)."""
    if PARAM in f.metadata:
        _, low, high, choices, _ = f.metadata[PARAM]
        problem = range_problem(value, low, high, choices)
        if problem:
            raise ValueError(f"{cls.__name__}.{f.name} {problem}, got {value!r}")


def _check_keys(cls, data: Mapping, where: str) -> None:
    unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ValueError(f"{where}: unknown keys {sorted(map(str, unknown))}")


def check_types(cls, data: Mapping, where: str) -> None:
    """data as from YAML (lists for tuples, ints for floats) against dataclass cls; `where`
    begins the message (e.g. "defaults" -> "defaults: speed must be a finite number, got 'fast'")."""
    _check_keys(cls, data, where)
    hints = typing.get_type_hints(cls)
    for key, value in data.items():
        hint = hints[key]
        if dataclasses.is_dataclass(hint) and isinstance(value, Mapping):
            check_types(hint, value, f"{where}: {key}")
        elif not _fits(hint, value):
            raise ValueError(f"{where}: {key} must be {_describe(hint)}, got {value!r}")


def as_hinted(hint, value):
    """A value that fits `hint` (float or tuple[...] fields; others are returned as they are),
    as the hint's type: a whole number given for a float is that float (YAML's `1000` and
    `1000.0` are one setting: one saved config, one digest), a list for a tuple that tuple, each
    element as its own hint. ValueError ("is too large for a number, ...") for a whole number
    too large for a float."""
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):    # X | None: as the alternative it fits
        fits = [a for a in args if _fits(a, value, finite=False)]
        return as_hinted(fits[0], value) if fits else value
    if hint is float and isinstance(value, int) and not isinstance(value, bool):
        try:
            return float(value)
        except OverflowError:
            raise ValueError(f"is too large for a number, got {value!r}") from None
    if origin is tuple and isinstance(value, (list, tuple)):
        if args and args[-1] is Ellipsis:
            return tuple(as_hinted(args[0], v) for v in value)
        return tuple(as_hinted(a, v) for a, v in zip(args, value)) if args else tuple(value)
    return value


def _fits(hint, value, finite: bool = True) -> bool:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return any(_fits(a, value, finite) for a in args)
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        if finite:
            return finite_number(value)
        return isinstance(value, (int, float)) and not isinstance(value, bool) and not _nan(value)
    if hint is str:
        return isinstance(value, str)
    if hint is dict or origin is dict:
        return isinstance(value, Mapping) and (not args or all(
            _fits(args[0], k, finite) and _fits(args[1], v, finite) for k, v in value.items()))
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            return False
        if origin is list or args[-1] is Ellipsis:
            return all(_fits(args[0], v, finite) for v in value)
        return len(value) == len(args) and all(_fits(a, v, finite) for a, v in zip(args, value))
    if dataclasses.is_dataclass(hint):
        return False     # a section given a value (a mapping is checked by check_types)
    return True          # no other kind of field is read from YAML


def finite_number(x) -> bool:
    """x is a real number (not a bool) and finite; an int too large for a float is not."""
    try:
        return isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
    except OverflowError:
        return False


def _nan(x: int | float) -> bool:
    return isinstance(x, float) and math.isnan(x)


def _describe(hint, finite: bool = True) -> str:
    origin, args = typing.get_origin(hint), typing.get_args(hint)
    if origin in (typing.Union, types.UnionType):
        return ", or ".join(_describe(a, finite) for a in args)
    if dataclasses.is_dataclass(hint):
        return f"a section ({hint.__name__})"
    if hint is dict or origin is dict:
        return (f"a mapping of {_describe(args[0], finite)} to {_describe(args[1], finite)}"
                if args else "a mapping")
    if origin is list or (origin is tuple and args[-1] is Ellipsis):
        return f"a list, each {_describe(args[0], finite)}"
    if origin is tuple:
        return f"a list of {len(args)} ({', '.join(_describe(a, finite) for a in args)})"
    number = "a finite number" if finite else "a number"
    return {type(None): "null", bool: "true or false", int: "an integer", float: number,
            str: "a string"}.get(hint, str(hint))


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
