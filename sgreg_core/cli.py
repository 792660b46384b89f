"""The `sgreg` command-line tool.

Each subcommand lives in its own module under sgreg_core/commands/ and exposes
`NAME`, `HELP`, `add_arguments(parser)` and `run(args) -> int`. Modules are imported only
when their subcommand runs, so `sgreg --help` stays fast and a broken optional dependency of
one command never takes the others down.
"""
from __future__ import annotations

import argparse
import importlib
import signal
import sys

# (subcommand, module under sgreg_core.commands, one-line help)
COMMANDS: list[tuple[str, str, str]] = [
    ("synth", "synth", "generate a synthetic indoor scene as an instance map directory"),
    ("graph", "graph", "build a scene graph from an instance map and draw it"),
    ("pairs", "pairs", "cut registration pairs with ground truth from a scan"),
    ("train", "train", "train the SG-Reg network"),
    ("bench-match", "bench_match", "benchmark node/point matching with ablations"),
    ("register", "register", "register two instance maps (prints T, writes JSON)"),
    ("bench-register", "bench_register", "benchmark registration against Open3D and KISS-Matcher"),
    ("bench-pose", "bench_pose", "time the robust estimator and its clique pyramid on synthetic correspondences"),
    ("make-bag", "make_bag", "simulate two agents in a scan and write a rosbag2 (MCAP)"),
    ("play", "play", "publish a recorded bag with its original timing"),
    ("record", "record", "record live topics into a rosbag2 (MCAP)"),
    ("bw", "bw", "per-topic bandwidth of live topics or of a bag"),
    ("agents", "agents", "start agent + registration nodes for N agents on this machine"),
    ("replay", "replay", "replay a two-agent bag through real nodes and score every estimate"),
    ("bench-replay", "bench_replay", "make and replay a suite of two-agent bags; success, wrong verified, time to success"),
]


def _load(module: str):
    return importlib.import_module(f"sgreg_core.commands.{module}")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sgreg",
        description="SG-Reg semantic scene-graph registration: tools for data, training, "
        "registration, bags and replay.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module, help_text in COMMANDS:
        sub.add_parser(name, help=help_text, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    # `sgreg ... | head` should end quietly, as other command-line tools do
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser()
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        return 0
    name = argv[0]
    entry = {n: (m, h) for n, m, h in COMMANDS}.get(name)
    if entry is None:
        parser.print_usage(sys.stderr)
        print(f"sgreg: unknown command '{name}' (see sgreg --help)", file=sys.stderr)
        return 2
    module_name, help_text = entry
    try:
        module = _load(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == f"sgreg_core.commands.{module_name}":
            print(f"sgreg {name}: not built yet in this version", file=sys.stderr)
            return 3
        raise
    sub = argparse.ArgumentParser(prog=f"sgreg {name}", description=help_text)
    module.add_arguments(sub)
    args = sub.parse_args(argv[1:])
    return int(module.run(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
