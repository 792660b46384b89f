"""sgreg agents --names a b [c ...]: the agent and registration nodes of N agents on this machine,
stopped cleanly on Ctrl-C."""
from __future__ import annotations

import signal
import sys
import time

NAME = "agents"
HELP = "start agent + registration nodes for N agents on this machine"


def add_arguments(p):
    p.add_argument("--names", nargs="+", required=True, help="agent ids, one namespace each")
    p.add_argument("--params-file", help="ROS parameter YAML (default: config/sgreg.yaml)")
    p.add_argument("--weights", help="model weights (.safetensors); default: the shipped model")
    p.add_argument("--log-dir", help="write each node's output to a file here instead of the terminal")
    p.add_argument("--keystore", help="fleet keystore (sgreg keys init): the nodes sign and check "
                                      "their messages; without it they run unauthenticated")


def run(args) -> int:
    from pathlib import Path

    from sgreg_core.runtime.auth import KeystoreError, is_agent_id
    from ..processes import DEFAULT_PARAMS, start_agents, stop

    if len(set(args.names)) != len(args.names) or not all(is_agent_id(n) for n in args.names):
        print("sgreg agents: agent names must be distinct agent ids: a letter, then letters, digits "
              "and single underscores (a, b, robot_1, ...)", file=sys.stderr)
        return 2
    try:
        _check_before_start(args)
    except (KeystoreError, OSError, ValueError) as exc:
        print(f"sgreg agents: {exc}", file=sys.stderr)
        return 2
    overrides = {k: v for k, v in (("weights_path", args.weights), ("keystore", args.keystore)) if v} or None
    procs = start_agents(args.names, args.params_file or DEFAULT_PARAMS, overrides,
                         Path(args.log_dir) if args.log_dir else None)
    print(f"started {len(procs)} nodes for agents {', '.join(args.names)}; Ctrl-C stops them", flush=True)
    stopping = False

    def on_signal(signum, frame):
        nonlocal stopping
        stopping = True

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    try:
        while not stopping:
            dead = [p for p in procs if p.proc.poll() is not None]
            if dead:
                for p in dead:
                    print(f"sgreg agents: {p.agent}/{p.executable} exited with {p.proc.returncode}", file=sys.stderr)
                return 1
            time.sleep(0.2)
    finally:
        stop(procs)
        print("all nodes stopped", flush=True)
    return 0


def _check_before_start(args) -> None:
    """What the nodes would otherwise find only once started (a node without its model or its
    key stays up and reports ERROR on /diagnostics, as a robot's node should, so `agents`
    would run on with nodes that do nothing): OSError, ValueError or KeystoreError in one line."""
    from sgreg_core.paths import make_folder, weights_files
    from sgreg_core.runtime.auth import Keystore

    from ..processes import check_params_file

    if args.weights:
        weights_files(args.weights)
    for line in check_params_file(args.params_file):
        print(f"sgreg agents: warning: --params-file {args.params_file}: {line}", file=sys.stderr)
    if args.keystore:
        keystore = Keystore(args.keystore)
        for name in args.names:
            keystore.signer(name)
    if args.log_dir:
        make_folder(args.log_dir)
