"""`sgreg synth OUT_DIR --seed S [--rooms N] [--kind apartment|office|building] [--run K]
[--noise ...] [--png]`.

Writes one synthetic scene as an instance map directory and prints its statistics.
"""
from __future__ import annotations

import argparse
import collections
import sys
import time
from pathlib import Path

NAME = "synth"
HELP = "generate a synthetic indoor scene as an instance map directory"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out_dir", help="instance map directory to write")
    parser.add_argument("--seed", type=int, default=0, help="seed of the scene")
    parser.add_argument("--rooms", type=int, default=1,
                        help="rooms (building: rooms along the corridor, besides it)")
    parser.add_argument("--kind", choices=["apartment", "office", "building"], default="apartment",
                        help="building: a floor of rooms on both sides of a corridor, in runs "
                             "of identical rooms (offices, hotel rooms)")
    parser.add_argument("--run", type=int, default=3, help="building: identical neighbouring rooms")
    parser.add_argument(
        "--noise", default="",
        help="front-end errors, comma list of NAME or NAME=RATE: confuse, merge, invent, jitter, "
             "overseg, drop, paraphrase, partial (tilt only tilts registration pairs); see "
             "sgreg pairs --help (default: none)")
    parser.add_argument("--png", action="store_true", help="also draw OUT_DIR/graph.png")


def run(args: argparse.Namespace) -> int:
    from sgreg_core.maps.instance_map import write_instance_map
    from sgreg_core.simulation.noise import NoiseConfig
    from sgreg_core.maps.scene_graph import build_scene_graph
    from sgreg_core.simulation.synth import SynthConfig, generate_scene

    out = Path(args.out_dir)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        # writing over another scene would leave its files (graph.png) beside the new maps
        print(f"sgreg synth: {out} exists and is not an empty folder; choose a new directory",
              file=sys.stderr)
        return 2
    try:
        noise = NoiseConfig.preset(args.noise)
        cfg = SynthConfig(kind=args.kind, rooms=args.rooms, run=args.run, noise=noise)
        t0 = time.perf_counter()
        imap = generate_scene(args.seed, cfg)
        t_gen = time.perf_counter() - t0
        write_instance_map(imap, args.out_dir)
    except (ValueError, OSError) as exc:
        print(f"sgreg synth: {exc}", file=sys.stderr)
        return 2
    graph = build_scene_graph(imap)
    labels = collections.Counter(imap.labels.values())
    print(f"scene: {args.kind}, {args.rooms} room(s), seed {args.seed}, generated in {t_gen * 1000:.0f} ms")
    print(f"points: {len(imap.points)} ({(imap.instance == 0).mean() * 100:.1f} % unlabelled), "
          f"extent {' x '.join(f'{e:.1f}' for e in imap.points.max(0) - imap.points.min(0))} m")
    print(f"instances: {len(imap.labels)}, nodes: {graph.num_nodes}, edges: {graph.num_edges}, "
          f"structural: {int(graph.structural.sum())}")
    print("labels: " + ", ".join(f"{k} x{v}" for k, v in labels.most_common()))
    if args.png:
        from sgreg_core.plots.graph import plot_scene_graph

        png = f"{args.out_dir.rstrip('/')}/graph.png"
        plot_scene_graph(graph, png, title=f"synth {args.kind} seed {args.seed}")
        print(f"picture: {png}")
    print(f"wrote {args.out_dir}")
    return 0
