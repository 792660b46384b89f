"""Verification of a candidate pose on the voxelised clouds (the function g of paper section V).

The reference cloud is voxelised once, its KD-tree and normals are built once, and every
candidate is scored against them: a source point is supported when its transformed position
has a reference neighbour within tau (point-to-point) and lies within tau/2 of that
neighbour's tangent plane (point-to-plane). Fitness is the supported share of source points,
the score a truncated (smooth) version of it used to rank candidates.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .. import geometry
from .solvers import apply_T


@dataclass
class Verification:
    """fitness: share of source points supported (point-to-point and point-to-plane);
    overlap: share of source points with a reference point within tau (point-to-point only);
    score: mean truncated point-to-plane score, in [0, 1]; rmse: point-to-point RMSE (m) of
    the supported points (inf when none)."""

    fitness: float
    overlap: float
    score: float
    rmse: float


def voxel_downsample(pts: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel (geometry.voxel_downsample, float64);
    non-finite points are dropped first."""
    pts = np.asarray(pts, np.float64)
    pts = pts[np.isfinite(pts).all(1)]
    if voxel <= 0 or pts.shape[0] == 0:
        return pts
    return geometry.voxel_downsample(pts, voxel).astype(np.float64)


def estimate_normals(pts: np.ndarray, tree: cKDTree, k: int = 10) -> np.ndarray:
    """Unit normals from the smallest principal axis of each point's k nearest neighbours."""
    k = min(k, pts.shape[0])
    _, nn = tree.query(pts, k=k)
    nb = pts[nn.reshape(pts.shape[0], k)]
    c = nb - nb.mean(1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", c, c)
    _, vecs = np.linalg.eigh(cov)
    return vecs[:, :, 0]


class CloudVerifier:
    """Scores candidate transforms of `src` onto `ref`; build once, call per candidate.

    voxel: voxel size (m) for both clouds; tau: support distance (m);
    max_src_points: the source is randomly subsampled (seeded) beyond this many points.
    """

    def __init__(self, src: np.ndarray, ref: np.ndarray, voxel: float = 0.05,
                 tau: float = 0.1, max_src_points: int = 5000, seed: int = 0):
        self.tau = float(tau)
        self.src = voxel_downsample(src, voxel)
        if self.src.shape[0] > max_src_points:
            pick = np.random.default_rng(seed).choice(self.src.shape[0], max_src_points,
                                                      replace=False)
            self.src = self.src[pick]
        self.ref = voxel_downsample(ref, voxel)
        self.valid = self.src.shape[0] >= 3 and self.ref.shape[0] >= 3
        if self.valid:
            self.tree = cKDTree(self.ref)
            self.normals = estimate_normals(self.ref, self.tree)

    def __call__(self, T: np.ndarray) -> Verification:
        if not self.valid:
            return Verification(0.0, 0.0, 0.0, np.inf)
        moved = apply_T(T, self.src)
        dist, nn = self.tree.query(moved, k=1, distance_upper_bound=self.tau)
        near = np.isfinite(dist)
        plane = np.zeros_like(dist)
        plane[near] = np.abs(np.einsum("ij,ij->i", moved[near] - self.ref[nn[near]],
                                       self.normals[nn[near]]))
        half = 0.5 * self.tau
        supported = near & (plane <= half)
        score = np.where(near, np.clip(1.0 - (plane / half) ** 2, 0.0, None), 0.0)
        rmse = float(np.sqrt(np.mean(dist[supported] ** 2))) if supported.any() else np.inf
        return Verification(fitness=float(supported.mean()), overlap=float(near.mean()),
                            score=float(score.mean()), rmse=rmse)
