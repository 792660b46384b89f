"""The `sgreg` command-line tool.

Each subcommand is a module of sgreg_cli/commands/ exposing `NAME`, `HELP`,
`add_arguments(parser)` and `run(args) -> int`; the command table is built from those modules.
They import their heavy dependencies (torch, Open3D, rclpy) inside `run`, so `sgreg --help`
stays fast; a module that fails to import is listed as unavailable, and the other commands
work on.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import signal
import sys
from types import ModuleType

from . import commands


def command_modules() -> tuple[dict[str, ModuleType], dict[str, str]]:
    """(NAME -> module) of every command module, and (module name -> why it failed to import)."""
    found, broken = {}, {}
    for info in pkgutil.iter_modules(commands.__path__):
        try:
            module = importlib.import_module(f"{commands.__name__}.{info.name}")
        except ImportError as exc:
            broken[info.name] = str(exc)
            continue
        found[module.NAME] = module
    return dict(sorted(found.items())), broken


class _HelpWithDefaults(argparse.HelpFormatter):
    """Help that names each option's default, unless its text already says what it is."""

    def _get_help_string(self, action):
        text = action.help or ""
        if (action.default in (None, "", [], argparse.SUPPRESS) or isinstance(action.default, bool)
                or "default" in text or not action.option_strings):
            return text
        return f"{text} (default: %(default)s)"


def build_parser(found: dict[str, ModuleType]) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sgreg",
        description="SG-Reg semantic scene-graph registration: tools for data, training, "
        "registration, bags and replay.",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, module in found.items():
        sub.add_parser(name, help=module.HELP, add_help=False)
    return parser


def main(argv: list[str] | None = None) -> int:
    # `sgreg ... | head` should end quietly, as other command-line tools do
    signal.signal(signal.SIGPIPE, signal.SIG_DFL)
    argv = sys.argv[1:] if argv is None else argv
    found, broken = command_modules()
    parser = build_parser(found)
    if not argv or argv[0] in ("-h", "--help"):
        parser.print_help()
        for name, why in broken.items():
            print(f"  ({name}: unavailable here: {why})")
        return 0
    module = found.get(argv[0])
    if module is None:
        parser.print_usage(sys.stderr)
        print(f"sgreg: unknown command '{argv[0]}' (see sgreg --help)", file=sys.stderr)
        return 2
    sub = argparse.ArgumentParser(prog=f"sgreg {argv[0]}", description=module.HELP,
                                  formatter_class=_HelpWithDefaults)
    module.add_arguments(sub)
    args = sub.parse_args(argv[1:])
    try:
        return int(module.run(args) or 0)
    except KeyboardInterrupt:
        # Ctrl-C is how a long command is stopped: one line, not a traceback (commands that
        # own their output, e.g. make-bag, remove what they had half-written)
        print(f"\nsgreg {argv[0]}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
