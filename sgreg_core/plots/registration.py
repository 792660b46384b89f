"""Top view of a registration: both clouds in REF's frame, one colour per side, and the node
matches drawn as lines (green when the estimate agrees with the match, red otherwise).

Public API:
    plot_registration(src_cloud, ref_cloud, T, out_path, src_nodes=None, ref_nodes=None,
                      title="", agree_radius=0.5, max_points=40000, seed=0) -> None
        src_cloud, ref_cloud: (N, 3) points in their own frames; T maps SRC into REF;
        src_nodes, ref_nodes: (m, 3) centers of matched nodes (row i matches row i).
        Writes a PNG (matplotlib, Agg backend, imported only when called).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..geometry import transform_points

SRC_COLOR, REF_COLOR = "tab:orange", "tab:blue"


def _subsample(pts: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    return pts[rng.choice(len(pts), n, replace=False)] if len(pts) > n else pts


def plot_registration(src_cloud, ref_cloud, T, out_path: str | Path, src_nodes=None,
                      ref_nodes=None, title: str = "", agree_radius: float = 0.5,
                      max_points: int = 40000, seed: int = 0) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rng = np.random.default_rng(seed)
    src = transform_points(T, np.asarray(src_cloud, np.float64).reshape(-1, 3))
    ref = np.asarray(ref_cloud, np.float64).reshape(-1, 3)
    fig, ax = plt.subplots(figsize=(9, 9), dpi=110)
    half = max_points // 2
    for pts, color, name in ((ref, REF_COLOR, "REF"), (src, SRC_COLOR, "SRC moved by T")):
        pts = _subsample(pts, half, rng)
        ax.scatter(pts[:, 0], pts[:, 1], s=0.4, c=color, alpha=0.5, linewidths=0, label=name)
    if src_nodes is not None and ref_nodes is not None and len(src_nodes):
        a = transform_points(T, np.asarray(src_nodes, np.float64).reshape(-1, 3))
        b = np.asarray(ref_nodes, np.float64).reshape(-1, 3)
        agree = np.linalg.norm(a - b, axis=1) < agree_radius
        for ok in (False, True):  # agreeing lines on top
            sel = agree == ok
            xs = np.stack([a[sel, 0], b[sel, 0]])
            ys = np.stack([a[sel, 1], b[sel, 1]])
            ax.plot(xs, ys, color="tab:green" if ok else "tab:red", lw=0.8, alpha=0.8)
        ax.scatter(b[:, 0], b[:, 1], s=12, c="black", zorder=3)
        ax.plot([], [], color="tab:green", label=f"node match, agrees ({int(agree.sum())})")
        ax.plot([], [], color="tab:red", label=f"node match, disagrees ({int((~agree).sum())})")
    ax.legend(loc="upper right", markerscale=10, fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m] (REF frame)")
    ax.set_ylabel("y [m]")
    ax.set_title(title)
    fig.tight_layout()
    Path(out_path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out_path)
    plt.close(fig)
