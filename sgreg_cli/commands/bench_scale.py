"""`sgreg bench-scale [--nodes 50 100 200 400] [--out results/bench_scale]`: how registration
grows with the graphs (sgreg_core/bench/scale_bench.py). Prints a table with the growth exponent
of each time (time ~ nodes^k), writes results.json with the resolved config, and scale.png."""
from __future__ import annotations

import argparse
import sys

NAME = "bench-scale"
HELP = "time coarse and dense registration, message sizes and memory against graph size"

COLUMNS = ("level_graph_ms", "encode_ms", "map_prep_ms", "coarse_ms", "dense_ms", "dense_requested_ms",
           "dense_point_match_ms", "dense_pose_gnc_ms", "dense_pose_clique_ms",
           "dense_pose_verify_ms", "dense_pose_competitor_ms")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--nodes", type=int, nargs="+", default=[50, 100, 200, 400],
                        help="graph sizes (objects)")
    parser.add_argument("--repeats", type=int, default=3, help="timed runs per size (the median is reported)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the synthetic scenes")
    parser.add_argument("--weights", help="model .safetensors (default: shipped)")
    parser.add_argument("--out", default="results/bench_scale", help="output folder (results.json, scale.png)")


def run(args: argparse.Namespace) -> int:
    import dataclasses
    import json
    import math

    import torch

    from sgreg_core.bench.scale_bench import ScaleConfig, growth, run_scale
    from sgreg_core.net.model import load_model
    from sgreg_core.paths import make_folder

    if min(args.nodes) < 5 or args.repeats < 1 or args.seed < 0:
        print("sgreg bench-scale: --nodes >= 5, --repeats >= 1 and --seed >= 0", file=sys.stderr)
        return 2
    try:
        out = make_folder(args.out)
    except OSError as exc:
        print(f"sgreg bench-scale: {exc}", file=sys.stderr)
        return 2
    torch.set_num_threads(1)
    cfg = ScaleConfig(nodes=tuple(sorted(args.nodes)), repeats=args.repeats, seed=args.seed)
    try:
        model = load_model(args.weights)
        rows = run_scale(model, cfg, log=lambda s: print(f"[bench-scale] {s}", flush=True))
    except (ValueError, FileNotFoundError) as exc:
        print(f"sgreg bench-scale: {exc}", file=sys.stderr)
        return 2
    keys = [k for k in COLUMNS if any(k in r for r in rows)]   # the estimator's steps vary
    for r in rows:
        for k in keys:
            r.setdefault(k, 0.0)
    print(f"\n{'nodes':>6} {'corr':>6} " + " ".join(f"{k[:-3]:>14}" for k in keys)
          + f" {'coarse kB':>10} {'dense kB':>9} {'peak MB':>8} {'ok c/d':>7}")
    for r in rows:
        print(f"{r['nodes']:6d} {r['correspondences']:6d} " + " ".join(f"{r[k]:14.1f}" for k in keys)
              + f" {r['coarse_message_kb']:10.1f} {r['dense_message_kb']:9.1f} {r['peak_rss_mb']:8.0f}"
              + f" {int(r['coarse_ok'])}/{int(r['dense_ok'])}")
    # one size, or a stage too fast to time, gives no growth (null in the JSON, which has no NaN)
    exponents = {k: (None if math.isnan(g) else g) for k in keys for g in [growth(rows, k)]}
    print("growth exponent k (time ~ nodes^k): " + (", ".join(f"{k[:-3]} {'-' if v is None else f'{v:.2f}'}"
                                                              for k, v in exponents.items())
                                                    if len(rows) > 1 else "needs two sizes or more"))
    (out / "results.json").write_text(json.dumps({"rows": rows, "growth_exponent": exponents,
                                                  "weights_id": model.weights_id,
                                                  "config": dataclasses.asdict(cfg)}, indent=1) + "\n")
    _plot(rows, keys, out / "scale.png")
    print(f"wrote {out / 'results.json'} and {out / 'scale.png'}")
    return 0


def _plot(rows, keys, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5))
    n = [r["nodes"] for r in rows]
    for k in keys:
        ax.loglog(n, [max(r[k], 1e-2) for r in rows], "o-", label=k[:-3])
    ax.loglog(n, [r["nodes"] ** 2 / n[0] ** 2 * rows[0]["dense_ms"] for r in rows], "k:", label="~ n^2")
    ax.set_xlabel("nodes per graph")
    ax.set_ylabel("ms (median)")
    ax.legend(fontsize=7)
    ax.set_title("registration time against graph size")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
