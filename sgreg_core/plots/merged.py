"""The merged map as a person would look at it: every agent's map, top-down, placed in the merged
frame by its pose, each agent in its own colour (the one it has in RViz: views.agent_rgb)."""
from __future__ import annotations

import numpy as np

from ..geometry import transform_points, voxel_downsample
from ..runtime.views import agent_rgb


def plot_merged_map(clouds: dict, poses: dict, out_path, title: str = "", voxel: float = 0.1,
                    note: str = "") -> None:
    """clouds: agent -> (N, 3) points in its map frame; poses: agent -> 4x4 T_merged<-agent
    (agents without a pose are listed as not attached)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 9))
    missing = []
    for k, agent in enumerate(sorted(clouds)):
        if agent not in poses:
            missing.append(agent)
            continue
        pts = transform_points(poses[agent], voxel_downsample(np.asarray(clouds[agent]), voxel))
        ax.scatter(pts[:, 0], pts[:, 1], s=0.4, color=agent_rgb(k) / 255.0, alpha=0.5, lw=0,
                   label=f"{agent} ({len(clouds[agent])} points)")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (merged frame)")
    ax.set_ylabel("y [m]")
    lines = [title] + ([note] if note else []) + ([f"not attached: {', '.join(missing)}"] if missing else [])
    ax.set_title("\n".join(l for l in lines if l), fontsize=10)
    legend = ax.legend(loc="upper right", markerscale=12, fontsize=8)
    for handle in legend.legend_handles:
        handle.set_alpha(1.0)
    fig.tight_layout()
    fig.savefig(out_path, dpi=110)
    plt.close(fig)
