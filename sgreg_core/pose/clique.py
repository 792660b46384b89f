"""Pairwise-compatibility graphs and their maximum cliques (paper section V, after G3Reg).

Two correspondences (p_i, q_i), (p_j, q_j) are compatible when a rigid motion preserves their
distance: | |p_i - p_j| - |q_i - q_j| | < delta. Inliers form a clique, so the maximum clique is
the largest mutually consistent set.

Maximum clique is NP-hard and igraph's exact solver (Cliquer) takes ~0.5 s on a random
1000-vertex graph, and building an igraph graph costs ~2 us per edge. So the exact search runs
only on a small kernel: a greedy clique gives a lower bound LB; only the LB-core (vertices with
>= LB neighbours inside it) can hold a larger clique; inside it, vertices adjacent to all
others (complement degree 0) or to all but one (complement degree 1) are decided by the
classic reduction rules. What is left goes to igraph.
"""
from __future__ import annotations

import sys
from dataclasses import dataclass

import numpy as np
from scipy.spatial.distance import pdist, squareform


def _igraph():
    """python-igraph, imported on first use without matplotlib: igraph loads it (when installed)
    for drawing, which sgreg never asks of it, and that alone costs ~0.4 s of every start-up."""
    block = "igraph" not in sys.modules and "matplotlib" not in sys.modules
    if block:
        sys.modules["matplotlib"] = None      # makes igraph's optional import fail fast
    try:
        import igraph
    finally:
        if block:
            del sys.modules["matplotlib"]
    return igraph


@dataclass
class CliqueResult:
    """indices: sorted correspondence indices of the clique. exact: False only when the kernel
    exceeded max_exact_vertices and a heuristic search stood in. delta: the level's bound (m).
    kernel: vertices that went to the exact solver."""

    indices: np.ndarray
    exact: bool
    delta: float
    kernel: int


def length_residuals(src: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(N, N) matrix of | |p_i - p_j| - |q_i - q_j| |, zero diagonal."""
    return squareform(np.abs(pdist(src) - pdist(ref)))


def compatibility(resid: np.ndarray, delta: float,
                  bounds: np.ndarray | None = None) -> np.ndarray:
    """Boolean adjacency of the compatibility graph at level `delta`.

    bounds: optional (N,) per-correspondence noise bounds; a pair's threshold never falls below
    b_i + b_j (the triangle-inequality limit for two inliers with those bounds).
    """
    adj = resid < delta
    if bounds is not None:
        adj |= resid < bounds[:, None] + bounds[None, :]
    np.fill_diagonal(adj, False)
    return adj


def _degrees(adj: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Neighbour counts of vertices `rows` among the vertex mask `cols` (no BLAS: the matvec
    threads fight other processes on a small machine and run 10x slower)."""
    return np.count_nonzero(adj[rows][:, cols], axis=1)


def _greedy_clique(adj: np.ndarray, degree: np.ndarray) -> np.ndarray:
    """Grow a clique by repeatedly taking the candidate with most neighbours among candidates.
    degree: every vertex's degree; it is kept as the degree among the remaining candidates by
    subtracting the rows of the vertices each step drops (O(n^2) in all, not per step)."""
    cand = np.ones(adj.shape[0], bool)
    deg = degree.copy()
    clique = []
    while cand.any():
        idx = np.flatnonzero(cand)
        if deg[idx].min() == idx.size - 1:
            # The candidates already form a clique: take them all at once.
            clique.extend(idx.tolist())
            break
        v = idx[int(np.argmax(deg[idx]))]
        clique.append(v)
        dropped = np.flatnonzero(cand & ~adj[v])   # v itself and its non-neighbours
        cand &= adj[v]
        deg -= np.count_nonzero(adj[dropped], axis=0)
    return np.asarray(clique, dtype=np.int64)


def _core(adj: np.ndarray, k: int, degree: np.ndarray) -> np.ndarray:
    """Mask of the k-core: peel every vertex of degree < k per round; the degrees are updated
    by the rows of the peeled vertices only."""
    alive = np.ones(adj.shape[0], bool)
    deg = degree.copy()
    while True:
        low = np.flatnonzero(alive & (deg < k))
        if low.size == 0:
            return alive
        alive[low] = False
        deg -= np.count_nonzero(adj[low], axis=0)


def _reduce(adj: np.ndarray, alive: np.ndarray) -> tuple[list[int], np.ndarray]:
    """Complement-degree 0/1 reductions. Returns (vertices forced into a maximum clique of the
    alive set, remaining kernel mask); clique(alive) = forced + clique(kernel)."""
    alive = alive.copy()
    forced: list[int] = []
    cdeg = np.zeros(adj.shape[0], np.int64)
    idx = np.flatnonzero(alive)
    cdeg[idx] = idx.size - 1 - _degrees(adj, idx, idx)
    while alive.any():
        zero = alive & (cdeg == 0)
        if zero.any():
            # Adjacent to every other alive vertex: in every maximum clique; removing them
            # leaves the complement degrees of the others unchanged.
            forced.extend(np.flatnonzero(zero).tolist())
            alive &= ~zero
            continue
        ones = np.flatnonzero(alive & (cdeg == 1))
        if ones.size == 0:
            break
        # u misses only w: some maximum clique holds u and not w (swap argument).
        u = int(ones[0])
        non = np.flatnonzero(alive & ~adj[u])
        w = int(non[non != u][0])
        forced.append(u)
        alive[u] = alive[w] = False
        cdeg -= alive & ~adj[w]
    return forced, alive


def max_clique(adj: np.ndarray, max_exact_vertices: int = 60) -> tuple[np.ndarray, bool, int]:
    """Maximum clique of a boolean adjacency matrix -> (sorted indices, exact, kernel size).

    If the reduced kernel still has more than `max_exact_vertices` vertices, igraph runs on
    the best-connected ones only and exact is False. The cap bounds the time: correspondences
    inside matched objects make kernels ~97% dense, where igraph's exact search grows from
    ~10 ms at 60 vertices to seconds at 100; the greedy clique is kept when it is larger.
    """
    n = adj.shape[0]
    if n == 0:
        return np.zeros(0, np.int64), True, 0
    degree = np.count_nonzero(adj, axis=1)
    best = _greedy_clique(adj, degree)
    # A clique larger than the greedy one needs every member to have >= len(best) neighbours.
    alive = _core(adj, best.size, degree)
    if not alive.any():
        return np.sort(best), True, 0
    forced, kernel = _reduce(adj, alive)
    kidx = np.flatnonzero(kernel)
    exact = True
    if kidx.size > max_exact_vertices:
        deg = _degrees(adj, kidx, kidx)
        kidx = kidx[np.argsort(-deg, kind="stable")[:max_exact_vertices]]
        exact = False
    found = np.asarray(forced, dtype=np.int64)
    if kidx.size:
        sub = adj[np.ix_(kidx, kidx)]
        iu, ju = np.nonzero(np.triu(sub, 1))
        g = _igraph().Graph(n=kidx.size, edges=np.stack([iu, ju], 1))
        cliques = g.largest_cliques()
        if cliques:
            found = np.concatenate([found, kidx[np.asarray(cliques[0], dtype=np.int64)]])
    if found.size > best.size:
        best = found
    return np.sort(best), exact, int(kidx.size)


def clique_pyramid(src: np.ndarray, ref: np.ndarray, deltas: tuple[float, ...],
                   bounds: np.ndarray | None = None,
                   max_exact_vertices: int = 60) -> list[CliqueResult]:
    """One maximum clique per compatibility level, the pairwise residuals computed once."""
    resid = length_residuals(src, ref)
    # pairs within their own bounds are compatible at every level: one mask for all levels
    floor = compatibility(resid, 0.0, bounds) if bounds is not None else False
    out = []
    for delta in deltas:
        idx, exact, k = max_clique(compatibility(resid, delta) | floor, max_exact_vertices)
        out.append(CliqueResult(indices=idx, exact=exact, delta=float(delta), kernel=k))
    return out
