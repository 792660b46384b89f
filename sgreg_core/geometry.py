"""Small geometry helpers shared by the data layer, metrics and the pose estimator.

Public API:
    transform_points(T, points) -> (N, 3)        apply a 4x4 rigid transform
    yaw_transform(yaw, t=(0, 0, 0)) -> (4, 4)    rotation about z by `yaw` (rad) then translation
    invert_transform(T) -> (4, 4)                inverse of a rigid transform
    voxel_coords(points, voxel) -> (N, 3) int64  integer voxel coordinates floor(p / voxel)
    pack_keys(columns) -> (N,) int64             one int64 key per row of integer columns
    voxel_downsample(points, voxel) -> (M, 3)    centroid of the points in each occupied voxel
"""
from __future__ import annotations

import numpy as np


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply the 4x4 transform T to (N, 3) points; keeps the input dtype."""
    points = np.asarray(points)
    T = np.asarray(T, dtype=np.float64)
    out = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    return out.astype(points.dtype if np.issubdtype(points.dtype, np.floating) else np.float64)


def yaw_transform(yaw: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 transform rotating by `yaw` radians about z, then translating by t."""
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = np.asarray(t, dtype=np.float64)
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (uses R^T rather than a general inverse)."""
    T = np.asarray(T, dtype=np.float64)
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def voxel_coords(points: np.ndarray, voxel: float) -> np.ndarray:
    """Integer voxel coordinates of each point."""
    return np.floor(np.asarray(points, dtype=np.float64) / voxel).astype(np.int64)


def pack_keys(columns: list[np.ndarray]) -> np.ndarray:
    """One int64 key per row so that rows are equal iff their keys are equal.

    Columns are shifted to start at 0 and bit-packed when they fit in 63 bits (the fast path
    used everywhere here); otherwise rows are numbered with np.unique(axis=0).
    """
    cols = [np.asarray(c, dtype=np.int64) for c in columns]
    if cols[0].size == 0:
        return np.zeros(0, dtype=np.int64)
    shifted = [c - c.min() for c in cols]
    bits = [max(int(s.max()).bit_length(), 1) for s in shifted]
    if sum(bits) > 63:
        _, inverse = np.unique(np.stack(cols, axis=1), axis=0, return_inverse=True)
        return inverse.reshape(-1).astype(np.int64)
    key = np.zeros_like(shifted[0])
    for s, b in zip(shifted, bits):
        key = (key << b) | s
    return key


def voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """Centroid of the points in each occupied voxel, float32 (M, 3)."""
    points = np.asarray(points, dtype=np.float32)
    if len(points) == 0:
        return points.reshape(0, 3)
    vc = voxel_coords(points, voxel)
    _, inverse, counts = np.unique(
        pack_keys([vc[:, 0], vc[:, 1], vc[:, 2]]), return_inverse=True, return_counts=True
    )
    sums = np.stack([np.bincount(inverse, weights=points[:, k]) for k in range(3)], axis=1)
    return (sums / counts[:, None]).astype(np.float32)
