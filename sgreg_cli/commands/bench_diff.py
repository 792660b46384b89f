"""`sgreg bench-diff BEFORE AFTER`: what changed between two `sgreg bench-replay` runs of one
suite (sgreg_core/bench/replay_diff.py): what was run differently, each bag whose verified or
wrong frames moved, the totals over the bags both ran, and the reasons for missed frames that
moved. --json FILE writes the same. Exit 1 when a bag published something wrong in AFTER (a
verified frame, or its merged frame on /tf) and nothing wrong in BEFORE (--fail-on-new-wrong),
else 0; 2 on bad input."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

NAME = "bench-diff"
HELP = "compare two bench-replay runs of one suite, bag by bag"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("before", help="bench-replay output folder (or its results.json)")
    p.add_argument("after", help="the run to compare with it")
    p.add_argument("--json", help="also write the comparison to this file")
    p.add_argument("--fail-on-new-wrong", action="store_true",
                   help="exit 1 when a bag published something wrong in AFTER (a verified frame or "
                   "the merged frame) and nothing wrong in BEFORE")


def _rate(o) -> str:
    return f"{100 * o.verified / o.registrable:.1f} % ({o.verified} of {o.registrable})" if o.registrable else "-"


def render(c, before: str, after: str) -> list[str]:
    lines = [f"before: {before}", f"after:  {after}"]
    for key, (b, a) in c.context.items():
        lines.append(f"  {key}: {b} -> {a}")
    if not c.context:
        lines.append("  the same weights, code, parameters and overrides (another timer phase or a re-run?)")
    if c.changed:
        width = max(len(n) for n in c.changed)
        lines.append(f"{'bag':{width}s}  verified / registrable   wrong verified   merged map wrong")
        for name, (b, a) in c.changed.items():
            lines.append(f"{name:{width}s}  {b.verified:4d}/{b.registrable:<4d} -> {a.verified:4d}/{a.registrable:<4d}"
                         f"   {b.wrong} -> {a.wrong}   {b.merged_wrong_s:.0f} s -> {a.merged_wrong_s:.0f} s"
                         f"{'   NEW WRONG' if name in c.new_wrong else ''}")
    lines.append(f"{c.common} bags in both, {len(c.changed)} changed")
    for side, names in (("before", c.only_before), ("after", c.only_after)):
        if names:
            lines.append(f"only in {side} (not in the totals): {', '.join(names)}")
    b, a = c.totals
    lines.append(f"success over registrable frames: {_rate(b)} -> {_rate(a)}")
    if None not in c.within_reach:
        lines.append(f"within reach of the link rules with each run's estimates: {c.within_reach[0]} of "
                     f"{b.registrable} -> {c.within_reach[1]} of {a.registrable}")
    lines.append(f"wrong verified: {b.wrong} -> {a.wrong}; merged map wrong: {b.merged_wrong_s:.0f} s -> "
                 f"{a.merged_wrong_s:.0f} s; bags with either: {c.bags_with_wrong[0]} -> {c.bags_with_wrong[1]}")
    moved = sorted(k for k in set(c.missed[0]) | set(c.missed[1]) if c.missed[0][k] != c.missed[1][k])
    if moved:
        lines.append("registrable frames missed, where the count moved:")
        lines += [f"  {cat} / {reason}: {c.missed[0][(cat, reason)]} -> {c.missed[1][(cat, reason)]}"
                  for cat, reason in moved]
    return lines


def as_json(c) -> dict:
    def o(x):
        return {"verified": x.verified, "registrable": x.registrable, "wrong_verified": x.wrong,
                "merged_wrong_s": x.merged_wrong_s}
    return {"bags_in_both": c.common,
            "changed": {n: {"before": o(b), "after": o(a)} for n, (b, a) in c.changed.items()},
            "only_before": c.only_before, "only_after": c.only_after,
            "totals": {"before": o(c.totals[0]), "after": o(c.totals[1])},
            "bags_with_wrong_published": {"before": c.bags_with_wrong[0], "after": c.bags_with_wrong[1]},
            "within_reach": {"before": c.within_reach[0], "after": c.within_reach[1]},
            "context_differences": {k: {"before": b, "after": a} for k, (b, a) in c.context.items()}}


def run(args: argparse.Namespace) -> int:
    from sgreg_core.bench.replay_diff import compare, load_run
    from sgreg_core.paths import output_file

    try:
        if args.json:
            output_file(Path(args.json))
        c = compare(load_run(args.before), load_run(args.after))
    except (OSError, ValueError) as exc:
        print(f"sgreg bench-diff: {exc}", file=sys.stderr)
        return 2
    print("\n".join(render(c, args.before, args.after)))
    if args.json:
        Path(args.json).write_text(json.dumps(as_json(c), indent=1))
    return 1 if args.fail_on_new_wrong and c.new_wrong else 0
