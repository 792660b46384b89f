"""Scene graph construction from an instance map (paper section IV-A).

Public API:
    GraphConfig                       dataclass of construction parameters (defaults below)
    build_scene_graph(imap, cfg=GraphConfig()) -> SceneGraph
    is_structural(label) -> bool      floor / wall / ceiling and their paraphrases
    STRUCTURAL_LABELS                 the label set behind is_structural

One node per labelled instance that has at least `min_points` points and a box diagonal of at
least `min_size`. A node holds its label, score, center (mean of its voxel-downsampled points,
so that sampling density does not bias it), extents (minimum-area box about z, found by a
vectorised coarse-to-fine search over `box_angles` orientations in [0, 90) deg; length >=
width; height = z range) and its voxel-downsampled points.

Edges, two rules:
* object - object: |o_i - o_j| < edge_factor * max(r_i, r_j) with r = half the box diagonal,
  capped at `max_radius` so that one long object (a 4 m curtain) does not link the whole room;
* structural nodes (floor, wall, ceiling ...) span the room, so the radius rule would link
  them to everything and their centers say little. They are linked to any node (object or
  structural) with a downsampled point in the same or an adjacent `contact_dist` grid cell
  as one of theirs: the floor links to what stands on it, a wall to what leans on it and to
  the walls it meets.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from ..config import param
from ..geometry import pack_keys, voxel_coords
from ..types import InstanceMap, SceneGraph

STRUCTURAL_LABELS = frozenset(
    {
        "wall", "walls", "wall surface", "partition", "partition wall",
        "floor", "floors", "flooring", "ground", "ground floor",
        "ceiling", "ceilings", "roof",
    }
)


def is_structural(label: str) -> bool:
    return label.strip().lower() in STRUCTURAL_LABELS


@dataclass
class GraphConfig:
    # m, node point clouds are downsampled to this grid
    voxel_size: float = param(0.05, "voxel size of node point clouds (m)", 0.01, 0.5)
    min_points: int = 30         # raw points; fewer -> the instance is dropped as noise
    min_size: float = 0.1        # m, minimum box diagonal of a kept node
    edge_factor: float = 2.0     # tau_d = edge_factor * max(r_i, r_j)  (paper's rule)
    max_radius: float = 2.0      # m, cap on r for the object rule
    contact_dist: float = 0.1    # m, contact cell size: structural node <-> node links when
                                 # their points lie in the same or adjacent cells (so points
                                 # closer than this always link, up to ~3.5x this may)
    box_angles: int = 90         # orientations tried for the minimum-area box (1 deg steps)

    def __post_init__(self):
        sizes = ("voxel_size", "edge_factor", "max_radius", "contact_dist")
        if not (all(0.0 < getattr(self, k) < np.inf for k in sizes) and 0.0 <= self.min_size < np.inf
                and self.min_points >= 1 and self.box_angles >= 1):
            raise ValueError(f"graph: {', '.join(sizes)} must be finite and > 0, min_size >= 0, "
                             f"min_points and box_angles >= 1")


def _runs(*cols: np.ndarray) -> np.ndarray:
    """Start index of each run of equal rows in already sorted columns."""
    change = np.zeros(len(cols[0]), dtype=bool)
    change[0] = True
    for c in cols:
        change[1:] |= c[1:] != c[:-1]
    return np.flatnonzero(change)


def _min_area_extents(xy: np.ndarray, node: np.ndarray, col: np.ndarray, n_angles: int) -> np.ndarray:
    """(n, 2) sorted (length, width) of the minimum-area rectangle of each node's points.

    Rows are sorted by node, then x cell (`col`), then y cell. Only the first and last point
    of each (node, x cell) column can be a hull vertex (up to a cell width), so the rest is
    dropped without any sort; the survivors are rotated by the candidate angles and reduced
    per node with reduceat. A rectangle is symmetric under 90 deg: angles in [0, 90) suffice.
    """
    first = _runs(node, col)
    last = np.r_[first[1:], len(node)] - 1
    keep = np.unique(np.r_[first, last])
    xy, node = xy[keep], node[keep]
    starts = _runs(node)
    n = np.diff(np.r_[starts, len(xy)])
    xy = xy - np.repeat(np.add.reduceat(xy, starts) / n[:, None], n, axis=0)
    # coarse-to-fine: every 5th candidate angle first, then the 9 around each node's best
    step = 0.5 * np.pi / n_angles
    coarse = np.arange(0, n_angles, 5) * step
    area, _, _ = _rotated_extents(xy, starts, np.broadcast_to(coarse, (len(starts), len(coarse))))
    fine = coarse[np.argmin(area, axis=1)][:, None] + np.arange(-4, 5) * step
    area, du, dv = _rotated_extents(xy, starts, fine)
    rows, best = np.arange(len(starts)), np.argmin(area, axis=1)
    ext = np.stack([du[rows, best], dv[rows, best]], axis=1)
    return -np.sort(-ext, axis=1)


def _rotated_extents(xy: np.ndarray, starts: np.ndarray, theta: np.ndarray):
    """Per node and candidate angle (theta: (n, A)): area and side lengths of the rotated box."""
    n = np.diff(np.r_[starts, len(xy)])
    c, s = np.repeat(np.cos(theta), n, axis=0), np.repeat(np.sin(theta), n, axis=0)
    u = xy[:, :1] * c + xy[:, 1:] * s         # (H, A)
    v = -xy[:, :1] * s + xy[:, 1:] * c
    du = np.maximum.reduceat(u, starts) - np.minimum.reduceat(u, starts)
    dv = np.maximum.reduceat(v, starts) - np.minimum.reduceat(v, starts)
    return du * dv, du, dv


def _object_edges(centers: np.ndarray, radius: np.ndarray, objects: np.ndarray, cfg: GraphConfig) -> np.ndarray:
    """Pairs (i, j), i < j, of objects with |o_i - o_j| < edge_factor * max(r_i, r_j), r capped
    at max_radius; sorted by (i, j).

    A k-d tree lists the candidates within the largest threshold, so memory follows the number
    of nearby pairs, not n^2; the rule itself is then applied to those pairs.
    """
    idx = np.flatnonzero(objects)
    if len(idx) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    c, r = centers[idx], np.minimum(radius[idx], cfg.max_radius)
    # a hair wider than the largest threshold, so that the tree's rounding cannot drop a pair
    reach = cfg.edge_factor * r.max() * (1 + 1e-9)
    i, j = cKDTree(c).query_pairs(reach, output_type="ndarray").T
    keep = np.linalg.norm(c[i] - c[j], axis=1) < cfg.edge_factor * np.maximum(r[i], r[j])
    i, j = i[keep], j[keep]
    order = np.lexsort((j, i))
    return np.stack([idx[i[order]], idx[j[order]]], axis=1)


def _structural_edges(points: np.ndarray, node: np.ndarray, structural: np.ndarray, cell: float) -> np.ndarray:
    """Pairs (s, j), s structural, s != j, where a point of node j lies in one of the 27 cells
    around a point of s (a `cell` grid anchored at the map's lowest corner); each pair once,
    sorted by (s, j).

    Only occupied cells are stored (a grid over the bounding box would grow with where a stray
    point lies): the distinct (cell, node) pairs, sorted by a packed cell key, in which the 27
    cells around each structural cell are found with searchsorted, as 9 ranges of 3 keys.
    """
    vc = voxel_coords(points - (points.min(0) - cell), cell)
    # Along each axis, shrink gaps of two or more cells to two: adjacency is unchanged and the
    # coordinates (from 1, under twice the number of points) pack into one int64 however far
    # apart the points lie.
    for a in range(3):
        u, inv = np.unique(vc[:, a], return_inverse=True)
        vc[:, a] = np.r_[1, 1 + np.cumsum(np.minimum(np.diff(u), 2))][inv]
    bits = [int(vc[:, a].max() + 1).bit_length() for a in range(3)]
    key = (vc[:, 0] << (bits[1] + bits[2])) | (vc[:, 1] << bits[2]) | vc[:, 2]
    order = np.lexsort((node, key))
    first = order[_runs(key[order], node[order])]
    key, node = key[first], node[first].astype(np.int64)   # distinct (cell, node), by key
    s_key, s_node = key[structural[node]], node[structural[node]]
    n = len(structural)
    codes = []
    for dx, dy in np.ndindex(3, 3):
        # the three cells along z have consecutive keys: one key range per (dx, dy)
        q = s_key + (((dx - 1) << (bits[1] + bits[2])) + ((dy - 1) << bits[2]))
        lo, hi = np.searchsorted(key, q - 1, "left"), np.searchsorted(key, q + 1, "right")
        cnt = hi - lo
        row = np.repeat(np.arange(len(q)), cnt)                    # query of each match
        at = np.arange(cnt.sum()) - np.repeat(np.cumsum(cnt) - cnt - lo, cnt)   # its entry
        s, j = s_node[row], node[at]
        codes.append(s[s != j] * n + j[s != j])
    codes = np.unique(np.concatenate(codes))
    return np.stack([codes // n, codes % n], axis=1)


def _empty_graph() -> SceneGraph:
    return SceneGraph(
        node_ids=np.zeros(0, np.int64), labels=[], scores=np.zeros(0, np.float32),
        centers=np.zeros((0, 3), np.float32), extents=np.zeros((0, 3), np.float32), points=[],
        edges=np.zeros((0, 2), np.int64), structural=np.zeros(0, bool),
    )


def build_scene_graph(imap: InstanceMap, cfg: GraphConfig | None = None) -> SceneGraph:
    """Build the scene graph of `imap` (see the module docstring for the rules)."""
    cfg = cfg or GraphConfig()
    # One sort of the ids gives labelled-ness, point counts and the node index of every point.
    ids, inverse, counts = np.unique(np.asarray(imap.instance), return_inverse=True, return_counts=True)
    kept = (ids > 0) & np.isin(ids, list(imap.labels)) & (counts >= cfg.min_points)
    if not kept.any():
        return _empty_graph()
    node_of_id = np.cumsum(kept) - 1
    sel = kept[inverse]
    node = node_of_id[inverse[sel]]
    pts = np.asarray(imap.points, dtype=np.float32)[sel]

    # Voxel-downsample every instance at once: sort by (node, vx, vy, vz), centroid per run.
    vc = voxel_coords(pts, cfg.voxel_size)
    order = np.argsort(pack_keys([node, vc[:, 0], vc[:, 1], vc[:, 2]]))
    pts, node, vc = pts[order], node[order], vc[order]
    vstart = _runs(node, vc[:, 0], vc[:, 1], vc[:, 2])
    down = np.add.reduceat(pts, vstart, dtype=np.float64) / np.diff(np.r_[vstart, len(pts)])[:, None]
    node, vx = node[vstart], vc[vstart, 0]

    starts = _runs(node)
    n_down = np.diff(np.r_[starts, len(down)])
    centers = np.add.reduceat(down, starts) / n_down[:, None]
    zext = np.maximum.reduceat(down[:, 2], starts) - np.minimum.reduceat(down[:, 2], starts)
    extents = np.concatenate([_min_area_extents(down[:, :2], node, vx, cfg.box_angles), zext[:, None]], axis=1)

    radius = 0.5 * np.linalg.norm(extents, axis=1)
    keep = 2 * radius >= cfg.min_size
    if not keep.any():
        return _empty_graph()
    node_ids = ids[kept][keep].astype(np.int64)
    labels = [imap.labels[int(i)] for i in node_ids]
    structural = np.array([is_structural(l) for l in labels], dtype=bool)
    down, node = down[keep[node]], (np.cumsum(keep) - 1)[node[keep[node]]]
    points = np.split(down.astype(np.float32), np.cumsum(n_down[keep])[:-1])
    centers, extents, radius = centers[keep], extents[keep], radius[keep]

    edges = [_object_edges(centers, radius, ~structural, cfg)]
    if structural.any():
        edges.append(_structural_edges(down, node, structural, cfg.contact_dist))
    edges = np.concatenate(edges)
    edges = np.unique(np.sort(edges, axis=1), axis=0) if len(edges) else edges.reshape(0, 2)
    return SceneGraph(
        node_ids=node_ids,
        labels=labels,
        scores=np.array([imap.scores.get(int(i), 1.0) for i in node_ids], dtype=np.float32),
        centers=centers.astype(np.float32),
        extents=extents.astype(np.float32),
        points=points,
        edges=edges.astype(np.int64),
        structural=structural,
    )
