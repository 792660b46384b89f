"""`sgreg view BAG --png OUT`: the merged map of a bag, top-down, each agent in its own colour.

Every agent's last instance map in the bag, placed by the merged frame the agents published on
/tf when the bag recorded it (a recorded replay: `sgreg record /tf /a/mapping/instances ...`),
else by the bag's ground truth (a bag made by `sgreg make-bag`), and the title says which.
"""
from __future__ import annotations

import sys
from pathlib import Path

NAME = "view"
HELP = "draw the merged map of a bag (recorded /tf, else ground truth) top-down"


def add_arguments(p):
    p.add_argument("bag", help="rosbag2 directory with the agents' maps (/<id>/mapping/instances) "
                   "and ground_truth.json or a recorded /tf")
    p.add_argument("--png", required=True, help="write the picture here")
    p.add_argument("--frame", default=None,
                   help="merged frame on /tf (default: the nodes' merged_frame, sgreg_merged)")


def run(args) -> int:
    import numpy as np

    from sgreg_core.geometry import invert_transform
    from sgreg_core.plots import figure_path
    from sgreg_core.plots.merged import plot_merged_map
    from sgreg_core.runtime.merge import MergeConfig

    from ..bags import BagError, final_maps, tf_in_bag
    from ..replay import ground_truth_of

    bag = Path(args.bag)
    try:
        figure_path(args.png)
        gt = ground_truth_of(bag, required=False)     # a recorded bag has none
        clouds = final_maps(bag, gt)
        tf = tf_in_bag(bag)
    except (BagError, OSError, ValueError) as exc:
        print(f"sgreg view: {exc}", file=sys.stderr)
        return 2
    if not clouds:
        print(f"sgreg view: {bag} holds no instance maps (record /<id>/mapping/instances with the "
              "agents' topics to draw it)", file=sys.stderr)
        return 2
    frame = args.frame or MergeConfig().merged_frame
    poses = {child.split("/")[0]: T for child, (parent, T) in tf.items() if parent == frame}
    if args.frame and not poses and tf:    # a frame typed wrong is said, not silently replaced
        print(f"sgreg view: the bag's /tf has no frame {frame} (its frames: "
              f"{', '.join(sorted({parent for parent, _ in tf.values()}))})", file=sys.stderr)
    if poses:
        source = f"placed by the merged frame on /tf ({frame})"
    elif gt is not None:
        anchor = min(gt["T_scene_map"])
        A = invert_transform(np.asarray(gt["T_scene_map"][anchor]))
        poses = {a: A @ np.asarray(T) for a, T in gt["T_scene_map"].items()}
        source = f"placed by the ground truth ({anchor}'s map frame)"
    else:
        print(f"sgreg view: {bag} has neither a recorded /tf in frame {frame} nor ground_truth.json",
              file=sys.stderr)
        return 2
    plot_merged_map(clouds, poses, args.png, title=f"{bag.name}: {len(clouds)} agents, {source}")
    print(f"{len(clouds)} agents ({', '.join(sorted(clouds))}), {source}: {args.png}")
    return 0
