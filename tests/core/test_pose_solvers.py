"""Closed-form fits, GNC-TLS and NMS of sgreg_core.pose."""
import numpy as np
import pytest

from sgreg_core.pose import (GncConfig, apply_T, fit_rigid, gnc_tls, make_T,
                             nms_correspondences)
from sgreg_core.geometry import yaw_rotation


def random_rotation(rng):
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def test_fit_rigid_recovers_se3_exactly():
    rng = np.random.default_rng(1)
    src = rng.uniform(-3, 3, (50, 3))
    T = make_T(random_rotation(rng), rng.uniform(-5, 5, 3))
    fit = fit_rigid(src, apply_T(T, src))
    assert fit.ok and fit.reason == "ok"
    np.testing.assert_allclose(fit.T, T, atol=1e-9)


def test_fit_rigid_weights_ignore_zero_weighted_outliers():
    rng = np.random.default_rng(2)
    src = rng.uniform(-3, 3, (40, 3))
    T = make_T(random_rotation(rng), rng.uniform(-5, 5, 3))
    ref = apply_T(T, src)
    ref[:10] += rng.uniform(-2, 2, (10, 3))
    w = np.ones(40)
    w[:10] = 0.0
    np.testing.assert_allclose(fit_rigid(src, ref, w).T, T, atol=1e-9)
    assert not np.allclose(fit_rigid(src, ref).T, T, atol=1e-3)


def test_fit_rigid_4dof_is_yaw_only():
    rng = np.random.default_rng(3)
    src = rng.uniform(-3, 3, (30, 3))
    T = make_T(yaw_rotation(2.5), [1.0, -2.0, 0.3])
    ref = apply_T(T, src) + rng.normal(0, 0.01, (30, 3))
    fit = fit_rigid(src, ref, dof=4)
    assert fit.ok
    R = fit.T[:3, :3]
    np.testing.assert_allclose(R[2], [0, 0, 1], atol=1e-12)  # no roll / pitch
    np.testing.assert_allclose(fit.T, T, atol=0.02)


@pytest.mark.parametrize("src,reason", [
    (np.zeros((2, 3)), "too_few_correspondences"),
    (np.c_[np.linspace(0, 5, 20), np.linspace(0, 2, 20), np.zeros(20)], "degenerate_geometry"),
    (np.ones((10, 3)), "degenerate_geometry"),
    (np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nan, 0, 0]]), "invalid_input"),
    (np.zeros((5, 2)), "invalid_input"),
])
def test_fit_rigid_degenerate_inputs_return_verdict(src, reason):
    fit = fit_rigid(src, src.copy())
    assert not fit.ok and fit.reason == reason
    np.testing.assert_array_equal(fit.T, np.eye(4))


def test_fit_rigid_4dof_vertical_line_is_degenerate():
    src = np.c_[np.zeros(10), np.zeros(10), np.linspace(0, 2, 10)]
    assert fit_rigid(src, src + 1.0, dof=4).reason == "degenerate_geometry"


@pytest.mark.parametrize("outlier_ratio", [0.0, 0.3, 0.6])
def test_gnc_tls_rejects_outliers(outlier_ratio):
    rng = np.random.default_rng(4)
    n = 300
    src = rng.uniform([0, 0, 0], [8, 6, 3], (n, 3))
    T = make_T(random_rotation(rng), rng.uniform(-5, 5, 3))
    ref = apply_T(T, src) + rng.normal(0, 0.01, (n, 3))
    k = int(outlier_ratio * n)
    ref[:k] = apply_T(T, rng.uniform([0, 0, 0], [8, 6, 3], (k, 3)))
    res = gnc_tls(src, ref, 0.1, cfg=GncConfig())
    assert res.ok
    assert np.linalg.norm(res.T[:3, 3] - T[:3, 3]) < 0.05
    truth = np.arange(n) >= k
    assert (res.inliers == truth).mean() > 0.97
    assert abs(res.inlier_ratio - (1 - outlier_ratio)) < 0.03


def test_gnc_tls_per_correspondence_bounds():
    rng = np.random.default_rng(5)
    src = rng.uniform(-3, 3, (100, 3))
    ref = src + rng.normal(0, 0.05, (100, 3))
    bounds = np.full(100, 0.5)
    bounds[:50] = 1e-3  # tight bounds make the noisy first half outliers
    res = gnc_tls(src, ref, bounds)
    assert res.inliers[50:].all() and not res.inliers[:50].any()


def test_nms_keeps_best_per_voxel_on_each_side():
    src = np.array([[0.01, 0.01, 0.01], [0.02, 0.02, 0.02], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]])
    ref = np.array([[5.0, 5.0, 5.0], [6.0, 6.0, 6.0], [7.01, 7.01, 7.01], [7.02, 7.02, 7.02]])
    scores = np.array([0.1, 0.9, 0.5, 0.7])
    # 0 and 1 share a source voxel (1 wins); 2 and 3 share a reference voxel (3 wins).
    np.testing.assert_array_equal(nms_correspondences(src, ref, scores, 0.05), [1, 3])
    np.testing.assert_array_equal(nms_correspondences(src, ref, scores, 0.0), [0, 1, 2, 3])
    # Without scores ties keep the first.
    np.testing.assert_array_equal(nms_correspondences(src, ref, None, 0.05), [0, 2])


def test_nms_thins_duplicate_clusters():
    rng = np.random.default_rng(6)
    centers = rng.uniform(0, 10, (20, 3))
    src = np.repeat(centers, 10, axis=0) + rng.uniform(0, 0.01, (200, 3))
    ref = src + 3.0
    keep = nms_correspondences(src, ref, rng.uniform(size=200), 0.2)
    assert 20 <= keep.size <= 20 * 8  # a 10-point cluster spans at most 8 voxels
    assert keep.size < 200
