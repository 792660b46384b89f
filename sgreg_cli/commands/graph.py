"""`sgreg graph SCAN_DIR [--png OUT]`: build the scene graph of an instance map, print its
statistics and build time, and optionally draw it."""
from __future__ import annotations

import argparse
import collections
import sys
import time

NAME = "graph"
HELP = "build a scene graph from an instance map and draw it"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scan_dir", help="instance map directory")
    parser.add_argument("--png", help="write a top-view picture of the graph here")
    parser.add_argument("--voxel", type=float, default=None, help="voxel size in m (default: GraphConfig.voxel_size, 0.05)")
    parser.add_argument("--repeat", type=int, default=5, help="builds to time (the best is reported)")


def run(args: argparse.Namespace) -> int:
    from sgreg_core.maps.instance_map import InstanceMapError, read_instance_map
    from sgreg_core.maps.scene_graph import GraphConfig, build_scene_graph
    from sgreg_core.plots import figure_path

    try:
        if args.repeat < 1:
            raise ValueError(f"--repeat must be >= 1, got {args.repeat}")
        cfg = GraphConfig() if args.voxel is None else GraphConfig(voxel_size=args.voxel)
        if args.png:
            figure_path(args.png)
        imap = read_instance_map(args.scan_dir)
    except (InstanceMapError, OSError, ValueError) as exc:
        print(f"sgreg graph: {exc}", file=sys.stderr)
        return 2
    times = []
    for _ in range(args.repeat):
        t0 = time.perf_counter()
        graph = build_scene_graph(imap, cfg)
        times.append(time.perf_counter() - t0)
    times.sort()
    labels = collections.Counter(graph.labels)
    print(f"points: {len(imap.points)}, instances: {len(imap.labels)}")
    print(f"nodes: {graph.num_nodes} ({int(graph.structural.sum())} structural), edges: {graph.num_edges}, "
          f"node points: {sum(len(p) for p in graph.points)}")
    print(f"build time: best {times[0] * 1000:.1f} ms, median {times[len(times) // 2] * 1000:.1f} ms "
          f"over {len(times)} runs")
    print("labels: " + ", ".join(f"{k} x{v}" for k, v in labels.most_common()))
    if args.png:
        from sgreg_core.plots.graph import plot_scene_graph

        plot_scene_graph(graph, args.png, title=args.scan_dir)
        print(f"picture: {args.png}")
    return 0
