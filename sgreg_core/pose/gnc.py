"""GNC-TLS: graduated non-convexity with a truncated-least-squares cost (Yang et al., RA-L 2020).

The TLS cost sum_i min(r_i^2 / c_i^2, 1) is approached from its convex surrogate: the control
parameter mu starts small (surrogate ~ least squares) and grows by `factor` each iteration
until the weights are binary. Each iteration is one weighted closed-form fit.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .solvers import fit_rigid, residuals


@dataclass
class GncConfig:
    """max_iters: GNC iterations (each one weighted fit); 100 is never reached in practice.
    factor:      growth of mu per iteration (1.4 as in the paper).
    tol:         stop when the TLS cost changes by less than this (relative).
    dof:         6 for SE(3), 4 for yaw + translation.
    """

    max_iters: int = 100
    factor: float = 1.4
    tol: float = 1e-6
    dof: int = 6


@dataclass
class GncResult:
    """T: (4, 4) estimate; inliers: bool mask (residual <= noise bound); inlier_ratio over all
    inputs; ok False (with reason) when no fit was possible; iterations run."""

    T: np.ndarray = field(default_factory=lambda: np.eye(4))
    inliers: np.ndarray = field(default_factory=lambda: np.zeros(0, bool))
    inlier_ratio: float = 0.0
    ok: bool = False
    reason: str = "invalid_input"
    iterations: int = 0


def gnc_tls(src: np.ndarray, ref: np.ndarray, noise_bound: float | np.ndarray,
            prior_weights: np.ndarray | None = None, cfg: GncConfig = GncConfig()) -> GncResult:
    """Robustly fit T (q = T p) to correspondences of which an unknown share are outliers.

    noise_bound: scalar or (N,) per-correspondence bound c_i (m) on an inlier's residual.
    prior_weights: optional (N,) confidences, multiplied into the GNC weights of every fit.
    """
    n = src.shape[0]
    c2 = np.broadcast_to(np.asarray(noise_bound, dtype=np.float64) ** 2, (n,))
    prior = np.ones(n) if prior_weights is None else np.asarray(prior_weights, np.float64)
    fit = fit_rigid(src, ref, prior, cfg.dof)
    if not fit.ok:
        return GncResult(inliers=np.zeros(n, bool), reason=fit.reason)
    T = fit.T
    r2 = residuals(T, src, ref) ** 2
    # mu so that the surrogate is convex over the largest residual seen.
    ratio_max = float(np.max(r2 / c2))
    it = 0
    if ratio_max > 1.0:
        mu = 1.0 / (2.0 * ratio_max - 1.0)
        prev_cost = np.inf
        for it in range(1, cfg.max_iters + 1):
            lo = mu / (mu + 1.0) * c2
            hi = (mu + 1.0) / mu * c2
            w = np.where(r2 <= lo, 1.0, 0.0)
            mid = (r2 > lo) & (r2 < hi)
            w[mid] = np.sqrt(c2[mid] * mu * (mu + 1.0) / r2[mid]) - mu
            fit = fit_rigid(src, ref, w * prior, cfg.dof)
            if not fit.ok:
                break
            T = fit.T
            r2 = residuals(T, src, ref) ** 2
            cost = float(np.sum(np.minimum(r2 / c2, 1.0)))
            binary = not mid.any()
            if binary and abs(prev_cost - cost) <= cfg.tol * max(cost, 1.0):
                break
            prev_cost = cost
            mu *= cfg.factor
    inliers = r2 <= c2
    return GncResult(T=T, inliers=inliers, inlier_ratio=float(inliers.mean()), ok=True,
                     reason="ok", iterations=it)
