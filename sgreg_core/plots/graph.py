"""Top view of a scene graph: points coloured by instance, node centers, edges, labels.

Public API:
    plot_scene_graph(graph, out_path, title="", max_points=60000, seed=0) -> None
        writes a PNG (matplotlib, Agg backend, imported only here and only when called)
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..types import SceneGraph


def plot_scene_graph(graph: SceneGraph, out_path: str | Path, title: str = "", max_points: int = 60000, seed: int = 0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(seed)
    fig, ax = plt.subplots(figsize=(10, 10), dpi=110)
    if graph.num_nodes:
        pts = np.concatenate(graph.points)
        owner = np.repeat(np.arange(graph.num_nodes), [len(p) for p in graph.points])
        if len(pts) > max_points:
            pick = rng.choice(len(pts), max_points, replace=False)
            pts, owner = pts[pick], owner[pick]
        palette = rng.uniform(0.15, 0.95, (graph.num_nodes, 3))
        palette[graph.structural] = 0.82  # structure in light grey so objects stand out
        order = np.argsort(~graph.structural[owner])  # structure drawn first, underneath
        ax.scatter(pts[order, 0], pts[order, 1], s=0.3, c=palette[owner[order]], linewidths=0)
        c = graph.centers
        for i, j in graph.edges:
            style = dict(color="tab:orange", lw=0.5, alpha=0.5) if graph.structural[i] or graph.structural[j] \
                else dict(color="tab:blue", lw=0.8, alpha=0.7)
            ax.plot([c[i, 0], c[j, 0]], [c[i, 1], c[j, 1]], **style)
        ax.scatter(c[:, 0], c[:, 1], s=np.where(graph.structural, 30, 18),
                   c=np.where(graph.structural, "tab:red", "black"), zorder=3)
        for k in range(graph.num_nodes):
            ax.annotate(graph.labels[k], c[k, :2], fontsize=6, xytext=(2, 2), textcoords="offset points")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(title or f"{graph.num_nodes} nodes, {graph.num_edges} edges")
    fig.tight_layout()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path)
    plt.close(fig)
