"""Yaw-and-translation poses fixed by two point matches of levelled maps.

Both maps are levelled before their graphs are built, so two matches (src[i] -> ref[i],
src[j] -> ref[j]) whose horizontal distances agree fix a pose: the yaw that turns the segment
i -> j of the source onto that of the reference, and the translation that puts their midpoints
together. Enumerating such pairs finds a pose that only a few right matches support even when
many wrong ones agree on another (the largest clique), and it finds every placement of a graph
on its look-alikes (pose/repeats.py).

Public API:
    yaw_hypotheses(src, ref, node, bound, min_pair_m, max_hypotheses, seed) -> (R, t)
    landed(R, t, src, alike, bound) -> (H, n) which matches each pose brings within bound
    placement_support(R, t, src, alike, bound) -> (H,) how many
    pair_poses(src, ref, bound, min_support, limit) -> [T], the best supported, one per consensus
"""
from __future__ import annotations

import numpy as np


def _pairs(m: int, max_hypotheses: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Index pairs i < j of m matches: all of them, or a seeded sample when there are many
    more than max_hypotheses (the full list of a large graph would not fit in memory)."""
    total = m * (m - 1) // 2
    if total <= 8 * max_hypotheses:
        return np.triu_indices(m, k=1)
    a, b = np.random.default_rng(seed).integers(0, m, (2, 8 * max_hypotheses))
    keep = a != b
    return np.minimum(a, b)[keep], np.maximum(a, b)[keep]


def yaw_hypotheses(src: np.ndarray, ref: np.ndarray, node: np.ndarray, bound: float,
                   min_pair_m: float, max_hypotheses: int, seed: int = 0):
    """(R (H, 3, 3), t (H, 3)): the yaw + translation of each two matches (src[i] -> ref[i]) of
    two different source nodes (`node`), at least min_pair_m apart horizontally in both maps
    (shorter pairs fix the yaw poorly) and their lengths agreeing within 2 bounds; a seeded
    subset beyond max_hypotheses."""
    i, j = _pairs(src.shape[0], max_hypotheses, seed)
    ds, dr = src[j] - src[i], ref[j] - ref[i]
    ls, lr = np.linalg.norm(ds[:, :2], axis=1), np.linalg.norm(dr[:, :2], axis=1)
    ok = ((node[i] != node[j]) & (ls >= min_pair_m) & (lr >= min_pair_m)
          & (np.abs(ls - lr) <= 2 * bound) & (np.abs(ds[:, 2] - dr[:, 2]) <= 2 * bound))
    i, j, ds, dr = i[ok], j[ok], ds[ok], dr[ok]
    if i.size > max_hypotheses:
        pick = np.sort(np.random.default_rng(seed).choice(i.size, max_hypotheses, replace=False))
        i, j, ds, dr = i[pick], j[pick], ds[pick], dr[pick]
    yaw = np.arctan2(dr[:, 1], dr[:, 0]) - np.arctan2(ds[:, 1], ds[:, 0])
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((yaw.size, 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    mid_s, mid_r = 0.5 * (src[i] + src[j]), 0.5 * (ref[i] + ref[j])
    t = mid_r - np.einsum("hij,hj->hi", R, mid_s)
    return R, t


def landed(R: np.ndarray, t: np.ndarray, src: np.ndarray, alike: np.ndarray,
           bound: float) -> np.ndarray:
    """(H, n) bool: source point i lands within `bound` of one of its candidates alike[i]
    under (R[h], t[h]). src (n, 3), alike (n, k, 3). In blocks of hypotheses, so that the
    temporaries stay near 100 MB however many there are."""
    block = max(1, 2_000_000 // max(1, alike.shape[0] * alike.shape[1]))
    out = np.zeros((R.shape[0], src.shape[0]), bool)
    for a in range(0, R.shape[0], block):
        moved = np.einsum("hij,nj->hni", R[a:a + block], src) + t[a:a + block, None, :]
        d = np.linalg.norm(moved[:, :, None, :] - alike[None], axis=-1)      # (h, n, k)
        out[a:a + block] = d.min(-1) <= bound
    return out


def placement_support(R: np.ndarray, t: np.ndarray, src: np.ndarray, alike: np.ndarray,
                      bound: float) -> np.ndarray:
    """(H,) source points within `bound` of one of their candidates under each (R[h], t[h])."""
    return landed(R, t, src, alike, bound).sum(1)


def pair_poses(src: np.ndarray, ref: np.ndarray, bound: float, min_support: int,
               limit: int = 24, min_pair_m: float = 0.5,
               max_hypotheses: int = 4000) -> list[np.ndarray]:
    """The poses two matches (src[i] -> ref[i]) fix that bring at least min_support matches
    within bound: at most `limit`, the best supported first, one per consensus: a pose whose
    set of matches within bound lies within a better supported pose's set is left out (every
    pair of one consensus fixes nearly the same pose; without this, the pairs of the largest
    consensus would take every place)."""
    src = np.asarray(src, np.float64).reshape(-1, 3)
    ref = np.asarray(ref, np.float64).reshape(-1, 3)
    n = src.shape[0]
    if n < 2 or limit < 1:
        return []
    R, t = yaw_hypotheses(src, ref, np.arange(n), bound, min_pair_m, max_hypotheses)
    inl = landed(R, t, src, ref[:, None], bound)
    support = inl.sum(1)
    order = np.argsort(-support, kind="stable")
    order = order[support[order] >= min_support]
    _, first = np.unique(inl[order], axis=0, return_index=True)
    kept: list[int] = []
    for h in order[np.sort(first)]:
        if len(kept) == limit:
            break
        # a set within a better supported one is that consensus seen through noisier pairs
        if kept and (~(inl[h] & ~inl[kept]).any(1)).any():
            continue
        kept.append(int(h))
    out = []
    for h in kept:
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R[h], t[h]
        out.append(T)
    return out
