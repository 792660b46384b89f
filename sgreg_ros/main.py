"""Entry points of the executables (`ros2 run sgreg_ros agent`, `sgreg-agent`,
`python -m sgreg_ros agent`). Light on purpose: the signal handlers are installed before the
node's module imports torch and loads the model (runner.py)."""
from __future__ import annotations

import os
import sys
from importlib import import_module

from . import EXECUTABLES
from .runner import run_node

_NODE_CLASSES = {"agent": ("sgreg_ros.agent_node", "AgentNode"),
                 "registration": ("sgreg_ros.registration_node", "RegistrationNode")}
assert set(_NODE_CLASSES) == set(EXECUTABLES)
_WHAT = {
    "agent": "turns the robot's instance map (mapping/instances) into a scene graph, sends it to "
             "the peers (sgreg/coarse) and answers their requests for points (sgreg/dense).",
    "registration": "registers the peers' scene graphs against the robot's own, publishes every "
                    "estimate (sgreg/registration), the verified ones (sgreg/transform) and the "
                    "merged frame of the fleet (/tf).",
}
USAGE = """usage: ros2 run sgreg_ros {exe} --ros-args -r __ns:=/<agent> [--params-file FILE] [-p NAME:=VALUE ...]

sgreg's {exe} node, one per robot: {what}
Its topics are /<agent>/...; the agent id is the namespace (or the agent_name parameter).
Every parameter with its default, range and description: config/sgreg.yaml (`sgreg params`),
or `ros2 param describe /<agent>/{exe} NAME` while the node runs."""


def wants_help(args: list[str]) -> bool:
    """-h / --help among the arguments before --ros-args (what the node itself would take)."""
    ours = args[: args.index("--ros-args")] if "--ros-args" in args else args
    return any(a in ("-h", "--help") for a in ours)


def run_executable(name: str, args=None) -> int:
    """Run the node; never returns. After the node shut down cleanly, the interpreter's own
    teardown (torch and the model loaded) would take another ~0.9 s, so the process ends here."""
    if wants_help(sys.argv[1:] if args is None else list(args)):
        print(USAGE.format(exe=name, what=_WHAT[name]))
        sys.stdout.flush()
        os._exit(0)
    module, cls = _NODE_CLASSES[name]
    code = run_node(lambda: getattr(import_module(module), cls), args)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def agent(args=None) -> int:
    return run_executable("agent", args)


def registration(args=None) -> int:
    return run_executable("registration", args)
