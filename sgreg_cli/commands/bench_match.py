"""`sgreg bench-match [--weights W ...]`: node / point matching quality and stage timings.

Pairs come from the held-out room only (never trained on, never validated on): partial views
of each capture and views of one capture against the other (rescans), yaw uniform in
[-180, 180); with --on val, from the training's validation split instead (synthetic scenes no
training pair comes from): what a choice between weights may rest on. Conditions: clean, noisy
(jitter, split, dropped and partial instances, paraphrases) and frontend (all of those plus
wrong classes, merged and invented instances and per-map tilt; bench.cases.VIEW_NOISE). Several weight files (the shipped model and its
ablations: no triplets, no shape feature, early fusion, each trained with
`sgreg train --set ...`) are compared on the same pairs in one run.

Prints one table row per (model, condition) and writes JSON (per-pair rows + summaries) and the
resolved configuration next to it (<out>.config.json).
"""
from __future__ import annotations

import argparse
import sys

from sgreg_core.paths import RESCAN_GT, SCANS

NAME = "bench-match"
HELP = "benchmark node/point matching with ablations"

COLUMNS = [("node_recall", "node R", "{:.3f}"), ("node_precision", "node P", "{:.3f}"),
           ("inlier_ratio", "inlier", "{:.3f}"), ("node_matches", "n.match", "{:.1f}"),
           ("point_matches", "p.match", "{:.0f}"), ("ms_text", "text", "{:.1f}"),
           ("ms_shape", "shape", "{:.1f}"), ("ms_gnn", "gnn", "{:.1f}"),
           ("ms_node_match", "n.mt", "{:.2f}"), ("ms_point_match", "p.mt", "{:.1f}"),
           ("ms_coarse_path", "coarse", "{:.1f}")]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--weights", nargs="*", default=[],
                        help="model .safetensors files (default: the shipped model)")
    parser.add_argument("--names", nargs="*", default=[], help="a name per weights file")
    parser.add_argument("--pairs", type=int, default=40, help="pairs per condition")
    parser.add_argument("--seed", type=int, default=1234, help="seed of the cut pairs")
    parser.add_argument("--scans", "--scans-dir", dest="scans_dir", default=SCANS,
                        help="real scans (default: ../shared/data/scans next to the repository)")
    parser.add_argument("--scan-prefix", default="scannet-picwoon_", help="scan directory prefix")
    parser.add_argument("--rescan-gt", default=RESCAN_GT, help="pseudo ground truth between captures")
    parser.add_argument("--room", "--val-room", dest="room", default="scene0005",
                        help="room the pairs are cut from (held out of training and validation)")
    parser.add_argument("--on", choices=("test", "val"), default="test",
                        help="test: the held-out room (to report); val: the validation split, "
                        "unseen synthetic scenes (to choose between weights)")
    parser.add_argument("--cache-dir", default="runs/cache/pairs", help="cut pairs are cached here")
    parser.add_argument("--text-cache", default="runs/cache/text_minilm.npz",
                        help="label embeddings are cached here")
    parser.add_argument("--min-iou", type=float, default=0.3, help="gt node pairs at/above this IoU")
    parser.add_argument("--inlier-threshold", type=float, default=0.1, help="m")
    parser.add_argument("--match", dest="match_overrides", action="append", default=[],
                        metavar="KEY=VALUE", help="override a MatchConfig entry of every model "
                        "(e.g. point_threshold=0.02); repeatable")
    parser.add_argument("--threads", type=int, default=1, help="torch threads")
    parser.add_argument("--out", default="results/bench_match.json",
                        help="JSON file to write (the resolved config goes beside it, <out>.config.json)")


def _name(path: str) -> str:
    from pathlib import Path

    p = Path(path)
    return p.parent.name if p.stem == "model" else p.stem


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import json
    from pathlib import Path

    import numpy as np
    import torch

    from sgreg_core.config import apply_overrides, from_dict, to_dict
    from sgreg_core.bench.cases import VIEW_NOISE
    from sgreg_core.net.dataset import DataConfig, PairSource, augment
    from sgreg_core.net.evaluate import evaluate_pairs, summarize
    from sgreg_core.net.model import DEFAULT_WEIGHTS, load_model
    from sgreg_core.net.text import TextEncoder

    if args.threads < 1 or args.pairs < 1 or args.seed < 0:
        print("sgreg bench-match: --threads and --pairs must be >= 1, --seed >= 0", file=sys.stderr)
        return 2
    torch.set_num_threads(args.threads)
    weights = args.weights or [str(DEFAULT_WEIGHTS)]
    names = args.names or [_name(w) for w in weights]
    if len(names) != len(weights):
        print("sgreg bench-match: --names needs one name per --weights file", file=sys.stderr)
        return 2
    text = TextEncoder(cache_path=args.text_cache)
    try:
        models = [load_model(w, text_encoder=text) for w in weights]
        overrides = apply_overrides({}, args.match_overrides)
        for model in models:
            # checked as a MatchConfig (names, types, ranges) before any model runs; the
            # matchers hold the model's MatchConfig object, so thresholds change in place
            checked = from_dict(type(model.cfg.match), overrides)
            for key in overrides:
                setattr(model.cfg.match, key, getattr(checked, key))
    except (FileNotFoundError, ValueError, RuntimeError) as exc:
        print(f"sgreg bench-match: {exc}", file=sys.stderr)
        return 2

    base = DataConfig(scans_dir=args.scans_dir, scan_prefix=args.scan_prefix, rescan_gt=args.rescan_gt,
                      test_rooms=(args.room,), val_pairs=args.pairs, cache_dir=args.cache_dir)
    conditions = {"clean": dataclasses.replace(base, noise_prob=0.0),
                  "noisy": dataclasses.replace(base, noise_prob=1.0, noise=VIEW_NOISE["noisy"]),
                  "frontend": dataclasses.replace(base, noise_prob=1.0, noise=VIEW_NOISE["frontend"])}
    pairs = {}
    try:
        for cond, cfg in conditions.items():
            print(f"[bench-match] {cond}: {args.pairs} pairs ({args.on} split; cut once, then cached)",
                  file=sys.stderr, flush=True)
            source = PairSource(cfg, args.on, args.seed)
            # each pair seen from its own random 4-DoF frames (yaw in [-180, 180)), seeded
            pairs[cond] = [augment(source.pair(k), np.random.default_rng([args.seed, k]))
                           for k in range(len(source))]
    except (FileNotFoundError, RuntimeError) as exc:
        print(f"sgreg bench-match: {exc}", file=sys.stderr)
        return 2

    results = []
    for name, path, model in zip(names, weights, models):
        for cond, cond_pairs in pairs.items():
            print(f"[bench-match] {name} on {len(cond_pairs)} {cond} pairs", file=sys.stderr, flush=True)
            rows = evaluate_pairs(model, cond_pairs, args.min_iou, args.inlier_threshold)
            results.append({"model": name, "weights": path, "weights_id": model.weights_id,
                            "condition": cond, "summary": summarize(rows), "pairs": rows})

    _print_table(results)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"results": results}, indent=1) + "\n")
    resolved = {"args": vars(args), "conditions": {c: to_dict(cfg) for c, cfg in conditions.items()},
                "models": {n: {"weights": w, "weights_id": m.weights_id, "config": m.cfg.to_dict()}
                           for n, w, m in zip(names, weights, models)}}
    config_path = out.with_name(out.stem + ".config.json")
    config_path.write_text(json.dumps(resolved, indent=1) + "\n")
    print(f"wrote {out} and {config_path}")
    return 0


def _print_table(results: list[dict]) -> None:
    width = max(len(r["model"]) for r in results) + 2
    head = f"{'model':<{width}}{'cond':<7}{'pairs':>6}" + "".join(f"{h:>9}" for _, h, _ in COLUMNS)
    print(head)
    print("-" * len(head))
    for r in results:
        s = r["summary"]
        cells = "".join(f"{fmt.format(s.get(key, float('nan'))):>9}" for key, _, fmt in COLUMNS)
        print(f"{r['model']:<{width}}{r['condition']:<7}{s['pairs']:>6}{cells}")
    print("times: ms per graph (text, shape, gnn) and per pair (node / point match), medians; "
          "coarse: text + gnn + node match (the coarse path)")
