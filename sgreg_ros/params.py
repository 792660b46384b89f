"""Typed ROS parameters from one table per node: type, default, range and description are
declared together, values are checked at start, and a bad value stops the node with one clear
line instead of a traceback."""
from __future__ import annotations

from dataclasses import dataclass

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor


class ParameterError(ValueError):
    """A parameter value the node refuses at start."""


@dataclass(frozen=True)
class Param:
    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple = ()


def declare_and_read(node, table: list[Param]) -> dict:
    """Declare every parameter of `table` on `node` and return {name: value}, validated."""
    values = {}
    for p in table:
        desc = ParameterDescriptor(description=p.description)
        if p.low is not None and isinstance(p.default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(p.low), to_value=float(p.high), step=0.0)]
        elif p.low is not None and isinstance(p.default, int) and not isinstance(p.default, bool):
            desc.integer_range = [IntegerRange(from_value=int(p.low), to_value=int(p.high), step=1)]
        if p.choices:
            desc.additional_constraints = f"one of {', '.join(map(str, p.choices))}"
        try:
            value = node.declare_parameter(p.name, p.default, desc).value
        except Exception as exc:  # rclpy raises several types for out-of-range / wrong-type values
            raise ParameterError(f"parameter '{p.name}': {exc}") from None
        if type(value) is not type(p.default) and not (isinstance(p.default, float) and isinstance(value, int)):
            raise ParameterError(f"parameter '{p.name}' must be {type(p.default).__name__}, got {value!r}")
        if p.low is not None and not (p.low <= value <= p.high):
            raise ParameterError(f"parameter '{p.name}' = {value} is outside [{p.low}, {p.high}]")
        if p.choices and value not in p.choices:
            raise ParameterError(f"parameter '{p.name}' = {value!r} is not one of {p.choices}")
        values[p.name] = value
    return values


def agent_name_from(node, configured: str) -> str:
    """The agent id: the 'agent_name' parameter, else the node's namespace ('/a' -> 'a')."""
    name = configured or node.get_namespace().strip("/")
    if not name or "/" in name:
        raise ParameterError("set 'agent_name' or run the node in a one-level namespace "
                             "(--ros-args -r __ns:=/a)")
    return name
