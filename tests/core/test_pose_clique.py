"""Compatibility graphs and exact maximum cliques of sgreg_core.pose.clique."""
import itertools

import numpy as np
import pytest

from sgreg_core.pose import clique_pyramid, compatibility, length_residuals, max_clique
from sgreg_core.pose.solvers import apply_T, make_T
from sgreg_core.geometry import yaw_rotation


def adjacency(n, edges):
    a = np.zeros((n, n), bool)
    for i, j in edges:
        a[i, j] = a[j, i] = True
    return a


def brute_force_clique_number(adj):
    n = adj.shape[0]
    for k in range(n, 0, -1):
        for c in itertools.combinations(range(n), k):
            if all(adj[i, j] for i, j in itertools.combinations(c, 2)):
                return k
    return 0


def test_max_clique_hand_built_graph():
    # A 4-clique {0,1,2,3}, a triangle {4,5,6} bridged to it, a pendant 7.
    edges = [(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3), (4, 5), (5, 6), (4, 6), (3, 4),
             (6, 7)]
    idx, exact, _ = max_clique(adjacency(8, edges))
    assert exact
    np.testing.assert_array_equal(idx, [0, 1, 2, 3])


def test_max_clique_beats_greedy_trap():
    # Vertex 0 has the highest degree but lies in no large clique; the 4-clique {5..8} wins.
    edges = [(0, k) for k in range(1, 5)] + [(0, 5)]
    edges += list(itertools.combinations(range(5, 9), 2))
    idx, exact, _ = max_clique(adjacency(9, edges))
    np.testing.assert_array_equal(idx, [5, 6, 7, 8])


@pytest.mark.parametrize("seed", range(6))
def test_max_clique_matches_brute_force_on_random_graphs(seed):
    rng = np.random.default_rng(seed)
    n = 14
    a = np.triu(rng.uniform(size=(n, n)) < 0.5, 1)
    a |= a.T
    idx, exact, _ = max_clique(a)
    assert exact
    sub = a[np.ix_(idx, idx)]
    assert sub[~np.eye(idx.size, dtype=bool)].all()  # it is a clique
    assert idx.size == brute_force_clique_number(a)


def test_compatibility_and_pyramid_find_inliers():
    rng = np.random.default_rng(7)
    n, k = 400, 40
    src = rng.uniform([0, 0, 0], [8, 6, 3], (n, 3))
    T = make_T(yaw_rotation(1.0), [2.0, -1.0, 0.0])
    ref = apply_T(T, src) + rng.normal(0, 0.005, (n, 3))
    ref[k:] = apply_T(T, rng.uniform([0, 0, 0], [8, 6, 3], (n - k, 3)))
    adj = compatibility(length_residuals(src, ref), 0.1)
    assert adj[:k, :k][~np.eye(k, dtype=bool)].all()
    assert not adj.diagonal().any() and (adj == adj.T).all()
    levels = clique_pyramid(src, ref, (0.1, 0.2, 0.4))
    assert [lv.delta for lv in levels] == [0.1, 0.2, 0.4]
    for lv in levels:
        assert set(range(k)) <= set(lv.indices.tolist())
        assert lv.indices.size <= k + 3  # a few chance-compatible outliers at most


def test_compatibility_per_correspondence_bounds_relax_threshold():
    resid = np.array([[0.0, 0.3], [0.3, 0.0]])
    assert not compatibility(resid, 0.1)[0, 1]
    assert compatibility(resid, 0.1, np.array([0.2, 0.2]))[0, 1]
