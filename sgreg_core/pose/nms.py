"""Non-maximum suppression of point correspondences.

Dense matching returns clusters of near-duplicate correspondences (neighbouring points of one
node pair matched to neighbouring points). They add no information but inflate inlier counts
and the size of the compatibility graph, so only the best-scoring correspondence per voxel of
side `radius` is kept, first on the source side, then on the reference side.
"""
from __future__ import annotations

import numpy as np


def _first_per_voxel(pts: np.ndarray, radius: float) -> np.ndarray:
    """Positions (into pts) of the first point of each occupied voxel."""
    keys = np.floor(pts / radius).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return np.sort(first)


def nms_correspondences(src: np.ndarray, ref: np.ndarray, scores: np.ndarray | None,
                        radius: float) -> np.ndarray:
    """Indices (ascending) of the correspondences kept; radius <= 0 keeps all.

    scores: (N,) higher is better; ties keep the lower index so results are deterministic.
    """
    n = src.shape[0]
    if radius <= 0 or n == 0:
        return np.arange(n)
    s = np.zeros(n) if scores is None else np.asarray(scores, np.float64)
    order = np.argsort(-s, kind="stable")
    order = order[_first_per_voxel(src[order], radius)]
    order = order[_first_per_voxel(ref[order], radius)]
    return np.sort(order)
