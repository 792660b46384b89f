"""Typed configs: every component has one dataclass whose defaults are the only source of its
settings. From plain dicts (YAML / JSON) and back, dotted overrides, and `param` fields, which
the ROS nodes declare as parameters (sgreg_ros/params.py) with the default, description and
valid range written here once.

Public API:
    param(default, help, low=None, high=None, choices=(), factory=None, live=False) -> dataclasses.Field
    node_params(cls) -> {field name: (default, help, low, high, choices, live)}
    from_dict(cls, data) / to_dict(cfg) / apply_overrides(data, ["a.b=1", ...])
"""
from __future__ import annotations

import dataclasses
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
    kwargs = {}
    for key, value in data.items():
        hint = hints[key]
        if dataclasses.is_dataclass(hint):
            if not isinstance(value, Mapping):
                raise ValueError(f"{cls.__name__}.{key} is a section ({hint.__name__}), "
                                 f"got {value!r}")
            value = from_dict(hint, value)
        elif typing.get_origin(hint) is tuple:
            value = tuple(value)
        kwargs[key] = value
    return cls(**kwargs)


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
