"""Small geometry helpers shared by the data layer, metrics and the pose estimator.

Public API:
    MAX_COORD_M                                  m, the largest coordinate of a map point
    transform_points(T, points) -> (N, 3)        apply a 4x4 rigid transform
    yaw_rotation(yaw) -> (3, 3)                  rotation about z by `yaw` (rad)
    yaw_transform(yaw, t=(0, 0, 0)) -> (4, 4)    rotation about z by `yaw` (rad) then translation
    invert_transform(T) -> (4, 4)                inverse of a rigid transform
    is_rotation(R) / is_rigid(T) -> bool         a finite 3x3 rotation (det +1) / 4x4 rigid transform
    voxel_coords(points, voxel) -> (N, 3) int64  integer voxel coordinates floor(p / voxel)
    pack_keys(columns) -> (N,) int64             one int64 key per row of integer columns
    voxel_downsample(points, voxel) -> (M, 3)    centroid of the points in each occupied voxel
    local_planes(points, k, tree=None) -> (normals (N, 3), eigenvalues (N, 3))
                                                 each point's plane from its k nearest neighbours
"""
from __future__ import annotations

import numpy as np


def transform_points(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply the 4x4 transform T to (N, 3) points; keeps the input dtype."""
    points = np.asarray(points)
    T = np.asarray(T, dtype=np.float64)
    out = points.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
    return out.astype(points.dtype if np.issubdtype(points.dtype, np.floating) else np.float64)


MAX_COORD_M = 10_000.0   # m, per coordinate: maps are of buildings, not continents


def yaw_rotation(yaw: float) -> np.ndarray:
    """Rotation about +z by `yaw` radians."""
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def yaw_transform(yaw: float, t=(0.0, 0.0, 0.0)) -> np.ndarray:
    """4x4 transform rotating by `yaw` radians about z, then translating by t."""
    T = np.eye(4)
    T[:3, :3] = yaw_rotation(yaw)
    T[:3, 3] = np.asarray(t, dtype=np.float64)
    return T


def invert_transform(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (uses R^T rather than a general inverse)."""
    T = np.asarray(T, dtype=np.float64)
    inv = np.eye(4)
    inv[:3, :3] = T[:3, :3].T
    inv[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inv


def is_rotation(R, tol: float = 1e-4) -> bool:
    """R is a finite 3x3 rotation within tol: orthonormal with determinant +1 (a reflection,
    orthonormal too, is none)."""
    try:
        R = np.asarray(R, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return (R.shape == (3, 3) and bool(np.isfinite(R).all())
            and np.allclose(R @ R.T, np.eye(3), atol=tol) and np.linalg.det(R) > 0)


def is_rigid(T, tol: float = 1e-4) -> bool:
    """T is a finite 4x4 rigid transform within tol: a rotation, a translation, (0, 0, 0, 1)."""
    try:
        T = np.asarray(T, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return (T.shape == (4, 4) and bool(np.isfinite(T).all()) and is_rotation(T[:3, :3], tol)
            and np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=tol))


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


def local_planes(points: np.ndarray, k: int, tree=None) -> tuple[np.ndarray, np.ndarray]:
    """Each point's local plane from its k nearest neighbours (itself included; tree: a
    scipy cKDTree of `points` when the caller has one): the unit normal (the smallest principal
    axis, sign arbitrary) and the eigenvalues of the neighbourhood's scatter matrix S, ascending,
    (N, 3) each. Where S vanishes (every neighbour at one point) the normal is +z.

    Closed form for symmetric 3x3 matrices, a third of the time of a batched np.linalg.eigh:
    the eigenvalues from the trigonometric solution of the characteristic cubic, the normal as
    the longest cross product of two rows of S - l_min I (rank 2: both rows are perpendicular
    to it, and the longest pair is the best conditioned). Rows whose two smallest eigenvalues
    nearly coincide (line-like neighbourhoods, their normal ill-defined anyway) lose digits in
    the cubic's arccos and are solved by eigh instead, so the result is eigh's throughout."""
    from scipy.spatial import cKDTree   # here: geometry's other helpers are imported everywhere

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if int(k) < 1:
        raise ValueError(f"local_planes: k must be >= 1, got {k!r}")
    k = min(int(k), len(pts))
    if k == 0:
        return np.zeros((0, 3)), np.zeros((0, 3))
    tree = cKDTree(pts) if tree is None else tree
    _, nn = tree.query(pts, k=k)
    nb = pts[nn.reshape(len(pts), k)]
    c = nb - nb.mean(1, keepdims=True)
    x, y, z = c[..., 0], c[..., 1], c[..., 2]
    s00, s11, s22 = (x * x).sum(1), (y * y).sum(1), (z * z).sum(1)
    s01, s02, s12 = (x * y).sum(1), (x * z).sum(1), (y * z).sum(1)
    # S = q I + p B with tr(B) = 0, |B| fixed: the eigenvalues are q + 2p cos(phi + 2 pi j / 3)
    q = (s00 + s11 + s22) / 3.0
    b00, b11, b22 = s00 - q, s11 - q, s22 - q
    p = np.sqrt((b00 * b00 + b11 * b11 + b22 * b22 + 2.0 * (s01 * s01 + s02 * s02 + s12 * s12)) / 6.0)
    det = b00 * (b11 * b22 - s12 * s12) - s01 * (s01 * b22 - s12 * s02) + s02 * (s01 * s12 - b11 * s02)
    r = np.divide(det, 2.0 * p ** 3, out=np.zeros_like(p), where=p > 0)   # p = 0: S = q I
    phi = np.arccos(np.clip(r, -1.0, 1.0)) / 3.0                          # rounding leaves [-1, 1]
    hi, lo = q + 2.0 * p * np.cos(phi), q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    values = np.stack([lo, 3.0 * q - hi - lo, hi], 1)
    rows = np.stack([np.stack([s00 - lo, s01, s02], 1), np.stack([s01, s11 - lo, s12], 1),
                     np.stack([s02, s12, s22 - lo], 1)], 1)
    cross = np.stack([np.cross(rows[:, 0], rows[:, 1]), np.cross(rows[:, 0], rows[:, 2]),
                      np.cross(rows[:, 1], rows[:, 2])], 1)
    length = np.linalg.norm(cross, axis=2)
    best = length.argmax(1)
    idx = np.arange(len(pts))
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    ok = length[idx, best] > 0
    normals[ok] = cross[idx[ok], best[ok]] / length[idx[ok], best[ok], None]
    close = values[:, 1] - values[:, 0] < 1e-3 * values[:, 2]
    if close.any():
        cc = c[close]
        values[close], vecs = np.linalg.eigh(np.einsum("nki,nkj->nij", cc, cc))
        normals[close] = vecs[:, :, 0]
    return normals, values
