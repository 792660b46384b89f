"""`sgreg params [--out FILE]`: the parameter file of the nodes, written from the parameters they
declare (which come from the config dataclasses: one source for each default, description and
range). config/sgreg.yaml is this output; a test keeps the two equal."""
from __future__ import annotations

import argparse
import json
import sys

NAME = "params"
HELP = "write the nodes' parameter file (every parameter, its default and description)"

HEADER = """\
# One parameter file for every agent: `/**` applies to the agent and registration nodes in any
# namespace; the agent id comes from the namespace (--ros-args -r __ns:=/a).
# Written by `sgreg params --out config/sgreg.yaml` from the config dataclasses, which hold every
# default, description and range (docs/ARCHITECTURE.md, "Configuration"): change them there.
# Parameters marked (live) take effect at once under `ros2 param set` (checked; an invalid value
# is refused with the reason); all others are read-only once the node runs.
/**:
  ros__parameters:
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", help="write here (default: print)")


def _value(v) -> str:
    return json.dumps(v) if isinstance(v, (str, list)) else str(v).lower() if isinstance(v, bool) else repr(v)


def parameter_file() -> str:
    from sgreg_ros.agent_node import PARAMS as AGENT
    from sgreg_ros.registration_node import PARAMS as REGISTRATION

    agent, registration = {p.name: p for p in AGENT}, {p.name: p for p in REGISTRATION}
    groups = [("both nodes", [p for n, p in agent.items() if n in registration]),
              ("agent node", [p for n, p in agent.items() if n not in registration]),
              ("registration node", [p for n, p in registration.items() if n not in agent])]
    lines = [HEADER.rstrip("\n")]
    for title, params in groups:
        lines.append(f"    # {title}")
        for p in params:
            bounds = f" [{p.low}, {p.high}]" if p.low is not None else ""
            choices = f" ({' | '.join(p.choices)})" if p.choices else ""
            live = " (live)" if p.live else ""
            lines.append(f"    {p.name}: {_value(p.default)}    # {p.description}{bounds}{choices}{live}")
    return "\n".join(lines) + "\n"


def run(args: argparse.Namespace) -> int:
    text = parameter_file()
    if not args.out:
        sys.stdout.write(text)
        return 0
    from sgreg_core.paths import output_file

    try:
        output_file(args.out).write_text(text)
    except OSError as exc:
        print(f"sgreg params: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    print(f"wrote {args.out}")
    return 0
