"""geometry.local_planes: the closed-form local plane fits that levelling and verification share."""
import numpy as np
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
    normals, values = local_planes(pts, 10)
    vals, vecs = scatter_eigh(pts, 10)
    assert np.allclose(values, vals, atol=1e-9 * vals.max())
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


def test_undefined_planes_and_tiny_inputs():
    same = np.ones((20, 3))            # every neighbour the same point: no plane
    normals, values = local_planes(same, 5)
    assert np.array_equal(normals, np.tile([0.0, 0.0, 1.0], (20, 1)))
    assert np.allclose(values, 0.0)
    normals, values = local_planes(np.zeros((0, 3)), 5)
    assert normals.shape == values.shape == (0, 3)
    normals, _ = local_planes(np.eye(3), 10)     # k larger than the cloud: all of it
    assert normals.shape == (3, 3) and np.isfinite(normals).all()
