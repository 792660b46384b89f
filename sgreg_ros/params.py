"""Typed ROS parameters declared from the configs' dataclasses: each `param` field
(sgreg_core/config.py) becomes a parameter of the same name, with its default, description
and range written once, beside the setting itself. Values are checked at start, and a bad value
stops the node with one clear line instead of a traceback.

At run time (`ros2 param set`) a `live` parameter is checked the same way and, when valid,
handed to the node, which applies it at once; an invalid value is rejected with the reason.
Every other parameter is declared read-only, so setting it is refused instead of silently
changing nothing."""
from __future__ import annotations

import difflib
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterable

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

from sgreg_core.config import node_params, range_problem
from sgreg_core.runtime.auth import is_agent_id


# parameters rclpy declares on every node itself
ROS_OWNED = ("use_sim_time", "start_type_description_service")
ROS_OWNED_PREFIXES = ("qos_overrides.",)


class ParameterError(ValueError):
    """A parameter value the node refuses at start."""


@contextmanager
def parameter_errors():
    """Building configs from parameters that are each in range but do not fit together
    (min_nodes > max_nodes): the config's ValueError becomes a ParameterError, so the node
    stops with its one line instead of a traceback."""
    try:
        yield
    except ValueError as exc:
        raise ParameterError(str(exc)) from None


@dataclass(frozen=True)
class Param:
    name: str
    default: object
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple = ()
    live: bool = False


def params_of(*configs, skip: tuple[str, ...] = ()) -> list[Param]:
    """The parameters of the `param` fields of the given config dataclasses (names in `skip`
    left out): what a node declares."""
    table = [Param(name, *spec) for cls in configs for name, spec in node_params(cls).items()
             if name not in skip]
    names = [p.name for p in table]
    if len(set(names)) != len(names):
        raise ValueError(f"two configs expose one parameter name: {sorted(names)}")
    return table


def pick(cls, values: dict) -> dict:
    """The keyword arguments of dataclass `cls` among the parameter values."""
    return {k: values[k] for k in node_params(cls) if k in values}


def check(p: Param, value):
    """`value` if it suits parameter p (type, range, choices); else ParameterError."""
    if value is None and isinstance(p.default, list):
        value = []   # rclpy gives an empty array ("-p peers:=[]") no type: None
    if type(value) is not type(p.default) and not (isinstance(p.default, float) and type(value) is int):
        raise ParameterError(f"parameter '{p.name}' must be {type(p.default).__name__}, got {value!r}")
    problem = range_problem(value, p.low, p.high, p.choices)
    if problem:
        raise ParameterError(f"parameter '{p.name}' {problem}, got {value!r}")
    return float(value) if isinstance(p.default, float) else value


def _float_names(table: list[Param]) -> set[str]:
    return {p.name for p in table if isinstance(p.default, float)}


def _as_double(item, floats: set[str]):
    """The rclpy Parameter `item`, a double when it gives an integer to a float parameter."""
    from rclpy.parameter import Parameter

    if item.name in floats and item.type_ == Parameter.Type.INTEGER:
        return Parameter(item.name, Parameter.Type.DOUBLE, float(item.value))
    return item


def declare_and_read(node, table: list[Param]) -> dict:
    """Declare every parameter of `table` on `node` and return {name: value}, validated."""
    values = {}
    overrides = overrides_of(node)
    floats = _float_names(table)
    for p in table:
        if p.name in overrides:
            # "view_period_s: 0" in a params file: declared as the double it is, so that
            # `ros2 param describe` and `dump` show a double, not an integer
            overrides[p.name] = _as_double(overrides[p.name], floats)
        desc = ParameterDescriptor(description=p.description)
        if isinstance(p.default, float):
            # a value of another type is refused by check() with the parameter's name, not by
            # rclpy's nameless type error; an integer is made the double it means (above, and
            # accept_live_changes for `ros2 param set ... coarse_rate_hz 2`)
            desc.dynamic_typing = True
        if p.low is not None and isinstance(p.default, float):
            desc.floating_point_range = [FloatingPointRange(from_value=float(p.low), to_value=float(p.high), step=0.0)]
        elif p.low is not None and isinstance(p.default, int) and not isinstance(p.default, bool):
            desc.integer_range = [IntegerRange(from_value=int(p.low), to_value=int(p.high), step=1)]
        if p.choices:
            desc.additional_constraints = f"one of {', '.join(map(str, p.choices))}"
        desc.read_only = not p.live
        try:
            value = node.declare_parameter(p.name, p.default, desc).value
        except Exception as exc:  # rclpy raises several types for out-of-range / wrong-type values
            raise ParameterError(f"parameter '{p.name}': {exc}") from None
        values[p.name] = check(p, value)
    return values


def unknown_parameters(given: Iterable[str], known: Iterable[str]) -> list[str]:
    """One line per name in `given` (a params file's or the command line's) that is neither in
    `known` nor one rclpy declares itself, naming the closest known one when there is a close
    one: ROS ignores such a name without a word, so a typo would silently leave the default."""
    known = sorted(set(known))
    lines = []
    for name in sorted(set(given)):
        if name in known or name in ROS_OWNED or name.startswith(ROS_OWNED_PREFIXES):
            continue
        close = difflib.get_close_matches(name, known, n=1)
        lines.append(f"'{name}' is not a parameter of sgreg's nodes: ignored"
                     + (f" (did you mean '{close[0]}'?)" if close else ""))
    return lines


def parameter_file_names(path) -> set[str]:
    """The parameter names a ROS parameter file gives sgreg's nodes: those of its blocks for
    any node, or for one named `agent` or `registration` in any namespace (a file shared with
    other nodes may name theirs); ValueError when the file is not a parameter file."""
    from pathlib import Path

    return {name for node, params in parameter_blocks(_read_text(Path(path)))
            if node.rstrip("/").rsplit("/", 1)[-1] in ("**", "*", "agent", "registration")
            for name in params}


def parameter_values_for(text: str, node: str) -> dict:
    """name -> value that a ROS parameter file (its text) gives the node of fully qualified
    name `node` (e.g. /a/registration): its blocks whose node name matches, a later block
    winning, as ROS applies them; ValueError when it is not a parameter file."""
    values: dict = {}
    for pattern, params in parameter_blocks(text):
        if _node_matches(pattern, node):
            values.update(params)
    return values


def parameter_blocks(text: str) -> list[tuple[str, dict]]:
    """(node name as the file gives it, e.g. /** or /a/registration, its parameters with
    nested mappings named with dots, as ROS does) per ros__parameters block of a ROS parameter
    file's text; ValueError when it is not a parameter file."""
    import yaml

    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise ValueError(f"not YAML ({getattr(exc, 'problem', None) or 'unreadable'}{where})") from None
    blocks: list[tuple[str, dict]] = []

    def walk(node, path: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                if k == "ros__parameters" and isinstance(v, dict):
                    blocks.append((path, flat(v, "")))
                else:      # nested namespaces: {a: {registration: {ros__parameters: ...}}}
                    walk(v, f"{path}/{str(k).strip('/')}" if path else str(k))

    def flat(params: dict, prefix: str) -> dict:
        out = {}
        for k, v in params.items():
            out.update(flat(v, f"{prefix}{k}.") if isinstance(v, dict) else {f"{prefix}{k}": v})
        return out

    walk(doc, "")
    if not blocks:
        raise ValueError("no 'ros__parameters' mapping in it (a ROS parameter file: "
                         "/**: {ros__parameters: {name: value}})")
    return blocks


def _node_matches(pattern: str, node: str) -> bool:
    """Whether a parameter file's node name matches a fully qualified node name: "*" stands
    for one name, "**" for any number of them (ROS's wildcards); a name without its leading
    slash is taken as fully qualified, as ROS does."""
    def match(p: list[str], n: list[str]) -> bool:
        if not p:
            return not n
        if p[0] == "**":
            return any(match(p[1:], n[i:]) for i in range(len(n) + 1))
        return bool(n) and p[0] in ("*", n[0]) and match(p[1:], n[1:])

    return match([t for t in pattern.split("/") if t], [t for t in node.split("/") if t])


def _read_text(path) -> str:
    try:
        return path.read_text()
    except UnicodeDecodeError:
        raise ValueError("not text") from None


def overrides_of(node) -> dict:
    """name -> rclpy Parameter: what a params file or -p gave the node, declared or not. rclpy
    (Jazzy) keeps them in this attribute and has no public accessor; read directly, so that a
    change of rclpy fails loudly in the node tests."""
    return node._parameter_overrides


def node_parameter_names() -> set[str]:
    """Every parameter of the agent and registration nodes: one params file serves both."""
    from .agent_node import PARAMS as AGENT
    from .registration_node import PARAMS as REGISTRATION

    return {p.name for p in AGENT + REGISTRATION}


def accept_live_changes(node, table: list[Param], apply) -> None:
    """Check parameters set at run time against `table` and hand the valid ones to
    apply({name: value}); an invalid value is refused with its reason (rclpy refuses read-only
    ones before this runs), an integer for a float parameter taken as the double it means.
    apply raises ValueError, before it changes anything, for values that do not fit together:
    the change is refused with its message.
    Register after declare_and_read: rclpy runs these callbacks for declarations too."""
    from rcl_interfaces.msg import SetParametersResult

    by_name = {p.name: p for p in table}

    def on_set(params) -> SetParametersResult:
        changes = {}
        for item in params:
            p = by_name.get(item.name)
            if p is None:   # use_sim_time and the other parameters rclpy owns
                continue
            if not p.live:
                return SetParametersResult(successful=False, reason=f"'{p.name}' is read-only at run time")
            try:
                changes[p.name] = check(p, item.value)
            except ParameterError as exc:
                return SetParametersResult(successful=False, reason=str(exc))
        if changes:
            try:
                apply(changes)
            except ValueError as exc:    # values that do not fit the others (min_nodes > max_nodes)
                return SetParametersResult(successful=False, reason=str(exc))
        return SetParametersResult(successful=True)

    floats = _float_names(table)
    # "ros2 param set ... coarse_rate_hz 2" sends an integer: stored as the double it means
    node.add_pre_set_parameters_callback(lambda params: [_as_double(item, floats) for item in params])
    node.add_on_set_parameters_callback(on_set)


def frame_ok(frame: str) -> bool:
    """Whether `frame` is a usable tf frame id: tokens as in agent ids, joined by '/'."""
    return bool(frame) and all(is_agent_id(t) for t in frame.split("/"))


def agent_name_from(node, configured: str) -> str:
    """The agent id, which is also the prefix of every topic of the node (/<id>/sgreg/...):
    the 'agent_name' parameter, else the node's namespace ('/a' -> 'a'). Both may be given only
    when they agree: topics in one namespace named for another agent would reach no peer."""
    namespace = node.get_namespace().strip("/")
    name = configured or namespace
    if not name or "/" in name:
        raise ParameterError("set 'agent_name' or run the node in a one-level namespace "
                             "(--ros-args -r __ns:=/a)")
    if not is_agent_id(name):
        raise ParameterError(f"agent name {name!r} cannot start a topic name: a letter, then "
                             "letters, digits and single underscores")
    if configured and namespace and configured != namespace:
        raise ParameterError(f"agent_name '{configured}' differs from the namespace '/{namespace}': "
                             "give one of them (the topics are /<agent>/sgreg/...)")
    return name
