"""`sgreg bench-register [--n N] [--rooms ...] [--methods ...] [--out DIR]`: registration
recall, false claims and time of sgreg (dense, coarse) and its peers (Open3D FPFH+RANSAC, FGR,
KISS-Matcher), all on the same seeded cases (see sgreg_core.bench.cases): partial views of the
held-out room, clean and noisy; rescans (held-out room first, the others flagged seen in
training); a view of the tested room against other rooms (no right answer).

Writes DIR/results.json (summary + a row per case and method), DIR/config.json (the resolved
BenchConfig, the weights and their id) and DIR/recall.png, and prints the tables.
"""
from __future__ import annotations

import argparse
import sys

NAME = "bench-register"
HELP = "benchmark registration against Open3D and KISS-Matcher"

TIMING_NOTE = ("sgreg_dense: instance maps in -> T out (both graphs built and encoded, node + "
               "point matching, pose + verification); sgreg_coarse: node matching + pose + "
               "verification from graphs already encoded; peers: raw points in -> T out")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--n", type=int, default=None, help="pairs per setting (default 10)")
    parser.add_argument("--seed", type=int, default=None, help="seed of every case (default 0)")
    parser.add_argument("--scans", default=None, help="directory of scans (instance maps)")
    parser.add_argument("--scan-prefix", default=None, help="scan directory prefix")
    parser.add_argument("--rooms", nargs="+", default=None,
                        help="tested rooms (default: scene0005, held out of training)")
    parser.add_argument("--held-out-rooms", nargs="*", default=None,
                        help="rooms the network never saw (default scene0005)")
    parser.add_argument("--rescan-gt", default=None, help='rescan_gt.json ("" skips rescans)')
    parser.add_argument("--rescan-seeds", type=int, default=None,
                        help="random transforms per rescan direction, held-out rooms (default 3)")
    parser.add_argument("--rescan-seen-seeds", type=int, default=None,
                        help="random transforms per rescan pair, rooms seen in training "
                        "(default 1)")
    parser.add_argument("--methods", nargs="+", default=None, help="subset of the methods")
    parser.add_argument("--settings", nargs="+", default=None, help="subset of the settings")
    parser.add_argument("--weights", default=None, help="model .safetensors (default: shipped)")
    parser.add_argument("--set", dest="overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override any BenchConfig entry, e.g. "
                        "pipeline.pose.verdict.min_inliers=10 (repeatable)")
    parser.add_argument("--out", default="results/bench_register", help="output directory")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def _config(args: argparse.Namespace):
    """BenchConfig from the defaults, then the flags, then --set overrides."""
    from sgreg_core.bench.register_bench import BenchConfig
    from sgreg_core.config import apply_overrides, from_dict, to_dict

    data = to_dict(BenchConfig())
    flags = {"cases.n": args.n, "cases.seed": args.seed, "cases.scans_dir": args.scans,
             "cases.scan_prefix": args.scan_prefix, "cases.rooms": args.rooms,
             "cases.held_out_rooms": args.held_out_rooms, "cases.rescan_gt": args.rescan_gt,
             "cases.rescan_seeds": args.rescan_seeds,
             "cases.rescan_seen_seeds": args.rescan_seen_seeds, "methods": args.methods,
             "settings": args.settings, "weights": args.weights}
    for key, value in flags.items():
        if value is not None:
            *parents, leaf = key.split(".")
            node = data
            for name in parents:
                node = node[name]
            node[leaf] = value
    apply_overrides(data, args.overrides)
    return from_dict(BenchConfig, data)


def _json_safe(v):
    """Plain JSON values: numpy scalars unwrapped, NaN / inf (undefined) become null."""
    import math

    if hasattr(v, "item") and not isinstance(v, (list, dict)):
        v = v.item()
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    return v


def run(args: argparse.Namespace) -> int:
    import json

    import numpy as np
    import torch
    from tqdm import tqdm

    from sgreg_core.bench import machine
    from sgreg_core.bench.cases import build_cases
    from sgreg_core.bench.register_bench import SGREG_METHODS, run_case
    from sgreg_core.bench.register_report import format_tables, plot_recall, summarize
    from sgreg_core.maps.instance_map import InstanceMapError
    from sgreg_core.config import to_dict
    from sgreg_core.net.model import load_model
    from sgreg_core.paths import make_folder
    from sgreg_core.pipeline import warm_up

    try:
        cfg = _config(args)
        out = make_folder(args.out)     # before the cases: an unusable --out loses no run
        model = None
        if any(m in cfg.methods for m in SGREG_METHODS):
            model = load_model(cfg.weights or None)
            warm_up(model)
        cases = build_cases(cfg.cases, cfg.settings)
        if not cases:     # tables of nothing would read as a benchmark that ran
            raise ValueError(f"no cases for settings {', '.join(cfg.settings)} (rescans need --rescan-gt; "
                             "different_rooms needs scans of other rooms)")
    except (InstanceMapError, ValueError, TypeError, FileNotFoundError, RuntimeError,
            OSError, KeyError) as exc:
        print(f"sgreg bench-register: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    torch.set_num_threads(cfg.threads)   # BenchConfig refuses fewer than 1
    host = machine.describe()
    before = machine.reference_ms()

    rows = []
    during: dict[str, list[float]] = {}     # setting -> reference times taken among its cases
    # into a log file (not a terminal) a frame every 30 s, not dozens of carriage returns
    bar = tqdm(cases, desc="bench-register", unit="case", disable=args.no_progress,
               mininterval=0.1 if sys.stderr.isatty() else 30.0)
    for i, case in enumerate(bar):
        bar.set_postfix_str(f"{case.setting} {case.name}")
        if i % machine.REFERENCE_EVERY == 0:
            during.setdefault(case.setting, []).append(machine.reference_ms(repeats=3))
        rows += run_case(model, case, cfg)
    host["reference_ms"] = {"before": before, "after": machine.reference_ms(),
                            "by_setting": {k: float(np.median(v)) for k, v in during.items()}}
    summary = summarize(rows)
    print(format_tables(summary))
    print(f"times: {TIMING_NOTE}")
    print(machine.summary_line(host))

    weights = {"weights": str(cfg.weights or "shipped"),
               "weights_id": model.weights_id if model is not None else None}

    (out / "results.json").write_text(json.dumps(_json_safe(
        {**weights, "timing": TIMING_NOTE, "machine": host, "summary": summary, "rows": rows}),
        indent=1) + "\n")
    (out / "config.json").write_text(json.dumps(
        {**weights, "config": to_dict(cfg), "argv": vars(args)}, indent=1) + "\n")
    plot_recall(summary, out / "recall.png")
    print(f"wrote {out / 'results.json'}, {out / 'config.json'}, {out / 'recall.png'}")
    return 0
