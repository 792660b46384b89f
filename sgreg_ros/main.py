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


def run_executable(name: str, args=None) -> int:
    """Run the node; never returns. After the node shut down cleanly, the interpreter's own
    teardown (torch and the model loaded) would take another ~0.9 s, so the process ends here."""
    module, cls = _NODE_CLASSES[name]
    code = run_node(lambda: getattr(import_module(module), cls), args)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def agent(args=None) -> int:
    return run_executable("agent", args)


def registration(args=None) -> int:
    return run_executable("registration", args)
