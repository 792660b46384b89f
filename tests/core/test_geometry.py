"""geometry.local_planes: the closed-form local plane fits that levelling and verification share."""
import numpy as np
import pytest
from scipy.spatial import cKDTree

from sgreg_core.geometry import local_planes


def scatter_eigh(pts: np.ndarray, k: int):
    """The reference: np.linalg.eigh of each point's neighbourhood scatter matrix."""
    _, nn = cKDTree(pts).query(pts, k=k)
    c = pts[nn] - pts[nn].mean(1, keepdims=True)
    return np.linalg.eigh(np.einsum("nki,nkj->nij", c, c))


def room_like(seed: int = 0) -> np.ndarray:
    """A floor, two walls, a box and scattered clutter: planes, edges, corners and noise."""
    rng = np.random.default_rng(seed)
    floor = np.c_[rng.uniform(0, 4, (800, 2)), rng.normal(0, 0.003, 800)]
    wall_x = np.c_[rng.normal(0, 0.003, 400), rng.uniform(0, 4, 400), rng.uniform(0, 2.5, 400)]
    wall_y = np.c_[rng.uniform(0, 4, 400), rng.normal(4, 0.003, 400), rng.uniform(0, 2.5, 400)]
    box = rng.uniform([1, 1, 0], [1.5, 1.4, 0.8], (300, 3))
    clutter = rng.uniform([0, 0, 0], [4, 4, 2.5], (100, 3))
    return np.concatenate([floor, wall_x, wall_y, box, clutter])


def test_normals_and_eigenvalues_match_eigh():
    pts = room_like()
    normals, values = local_planes(pts, 10, cKDTree(pts))
    vals, vecs = scatter_eigh(pts, 10)
    assert (np.abs(values - vals) <= 1e-9 * vals[:, 2:]).all()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=1), 1.0, atol=1e-12)
    # sign is arbitrary; where the smallest eigenvalue is distinct the normal is unique
    distinct = vals[:, 1] - vals[:, 0] > 1e-6 * vals[:, 2]
    assert distinct.mean() > 0.9
    dots = np.abs(np.einsum("ij,ij->i", normals, vecs[:, :, 0]))
    assert dots[distinct].min() > 1 - 1e-9


def test_a_plane_gives_its_normal_and_a_zero_smallest_eigenvalue():
    rng = np.random.default_rng(1)
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    pts = np.c_[rng.uniform(-1, 1, (500, 2)), np.zeros(500)] @ R.T
    normals, values = local_planes(pts, 8)
    assert np.abs(normals @ R[:, 2]).min() > 1 - 1e-9
    assert (values[:, 0] <= 1e-12 * values[:, 2]).all()


def test_line_like_neighbourhoods_get_eighs_normal():
    """Where the two smallest eigenvalues nearly coincide the closed form loses digits: those
    rows must still come out as eigh gives them (the normal is perpendicular to the line)."""
    rng = np.random.default_rng(4)
    t = rng.uniform(0, 3, 400)
    line = np.c_[t, 0.5 * t, 0.2 * t] + rng.normal(0, 1e-5, (400, 3))
    normals, values = local_planes(line, 8)
    vals, vecs = scatter_eigh(line, 8)
    assert (np.abs(values - vals) <= 1e-9 * vals[:, 2:]).all()
    axis = np.array([1.0, 0.5, 0.2]) / np.linalg.norm([1.0, 0.5, 0.2])
    assert np.abs(normals @ axis).max() < 0.05     # the noise tilts each short stretch a little
    # without the fallback to eigh these normals are up to 1e-3 off, 1 at a tenth of the noise
    assert np.abs(np.einsum("ij,ij->i", normals, vecs[:, :, 0])).min() > 1 - 1e-9


def test_undefined_planes_and_tiny_inputs():
    same = np.ones((20, 3))            # every neighbour the same point: no plane
    normals, values = local_planes(same, 5)
    assert np.array_equal(normals, np.tile([0.0, 0.0, 1.0], (20, 1)))
    assert np.allclose(values, 0.0)
    normals, values = local_planes(np.zeros((0, 3)), 5)
    assert normals.shape == values.shape == (0, 3)
    normals, values = local_planes(np.eye(3), 10)     # k larger than the cloud: all of it
    assert np.allclose(np.abs(normals), 1.0 / np.sqrt(3.0)) and np.allclose(values[:, 0], 0.0)
    normals, _ = local_planes(np.random.default_rng(5).random((6, 3)), 1)   # itself alone
    assert np.array_equal(normals, np.tile([0.0, 0.0, 1.0], (6, 1)))
    with pytest.raises(ValueError):
        local_planes(np.eye(3), 0)
