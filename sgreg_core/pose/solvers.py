"""Weighted closed-form rigid fits (Kabsch/Umeyama) in SE(3) and in 4-DoF (yaw + translation).

The fits never raise: degenerate inputs (too few points, collinear or coincident points,
non-finite values, zero weights) come back as a `RigidFit` with ok=False and a reason, so the
estimator can turn them into a verdict instead of a wrong pose.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..geometry import yaw_rotation

# Relative size below which a principal spread counts as zero (collinear / coincident points).
_DEGENERATE_RATIO = 1e-3
# Absolute spread (metres) below which points count as coincident.
_MIN_SPREAD_M = 1e-6


@dataclass
class RigidFit:
    """Result of a closed-form fit. T maps source points onto reference points (q = R p + t).

    T:      (4, 4) float64, identity when ok is False.
    ok:     False when the input could not determine the transform.
    reason: "ok", "too_few_correspondences", "degenerate_geometry" or "invalid_input".
    """

    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    ok: bool = False
    reason: str = "invalid_input"


def make_T(R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Stack a rotation and a translation into a 4x4 homogeneous transform."""
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = t
    return T


def apply_T(T: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Transform (N, 3) points by a 4x4 transform."""
    return pts @ T[:3, :3].T + T[:3, 3]


def _check(src: np.ndarray, ref: np.ndarray, w: np.ndarray | None) -> tuple[str, np.ndarray]:
    """Validate shapes/values; return (reason, normalised weights)."""
    if src.ndim != 2 or src.shape[1] != 3 or src.shape != ref.shape:
        return "invalid_input", np.empty(0)
    n = src.shape[0]
    w = np.ones(n) if w is None else np.asarray(w, dtype=np.float64).reshape(-1)
    if w.shape[0] != n:
        return "invalid_input", np.empty(0)
    if not (np.isfinite(src).all() and np.isfinite(ref).all() and np.isfinite(w).all()):
        return "invalid_input", np.empty(0)
    if (w < 0).any():
        return "invalid_input", np.empty(0)
    return "ok", w


def fit_rigid(src: np.ndarray, ref: np.ndarray, weights: np.ndarray | None = None,
              dof: int = 6) -> RigidFit:
    """Weighted least-squares rigid transform minimising sum_i w_i |q_i - (R p_i + t)|^2.

    dof=6: full SE(3) (Kabsch with reflection guard). dof=4: rotation restricted to yaw about z,
    since maps are gravity-aligned (roll/pitch known from the IMU).
    Correspondences with zero weight do not count towards the minimum of 3.
    """
    src = np.asarray(src, dtype=np.float64)
    ref = np.asarray(ref, dtype=np.float64)
    reason, w = _check(src, ref, weights)
    if reason != "ok":
        return RigidFit(reason=reason)
    active = w > 0
    if active.sum() < 3:
        return RigidFit(reason="too_few_correspondences")
    wn = w / w.sum()
    cs = wn @ src
    cr = wn @ ref
    ps = src - cs
    pr = ref - cr
    if dof == 4:
        # Horizontal spread alone determines yaw; vertical spread is irrelevant here.
        spread = np.sqrt(wn @ (ps[:, :2] ** 2).sum(1))
        if spread < _MIN_SPREAD_M:
            return RigidFit(reason="degenerate_geometry")
        sxx = wn @ (ps[:, 0] * pr[:, 0] + ps[:, 1] * pr[:, 1])
        sxy = wn @ (ps[:, 0] * pr[:, 1] - ps[:, 1] * pr[:, 0])
        R = yaw_rotation(np.arctan2(sxy, sxx))
    elif dof == 6:
        # Collinear sources leave the rotation about their line undetermined.
        sv = np.linalg.svd(ps * np.sqrt(wn)[:, None], compute_uv=False)
        if sv[0] < _MIN_SPREAD_M or sv[1] < _DEGENERATE_RATIO * sv[0]:
            return RigidFit(reason="degenerate_geometry")
        H = (ps * wn[:, None]).T @ pr
        U, _, Vt = np.linalg.svd(H)
        D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0])
        R = Vt.T @ D @ U.T
    else:
        return RigidFit(reason="invalid_input")
    return RigidFit(T=make_T(R, cr - R @ cs), ok=True, reason="ok")


def residuals(T: np.ndarray, src: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Euclidean residuals |q_i - T p_i| for every correspondence."""
    return np.linalg.norm(ref - apply_T(T, src), axis=1)


def principal_spread(pts: np.ndarray) -> np.ndarray:
    """Standard deviations (m) of points along their principal axes, largest first."""
    if pts.shape[0] < 2:
        return np.zeros(3)
    sv = np.linalg.svd(pts - pts.mean(0), compute_uv=False) / np.sqrt(pts.shape[0])
    return np.pad(sv, (0, 3 - sv.shape[0]))
