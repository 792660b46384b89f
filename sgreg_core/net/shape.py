"""Shape network (paper section IV-D): per-point features Z_i and a node shape feature F_i.

The paper runs a KPConv pyramid over the whole scene (up to 900 ms of CPU pre-processing). Our
whole dense registration has 250 ms on 2 cores, so each node is encoded on its own: K_p points
sampled from the node cloud, expressed relative to the node center, and two rounds of kNN edge
convolution (DGCNN-lite) in that local frame give H and F. The point features Z then add what
the paper's scene-wide backbone sees beyond the node: where the point lies relative to the
nearest other nodes (PointEncoder).

Yaw invariance is built in rather than learnt from augmentation: every geometric input is a
length, a height or a component along a direction that turns with the node,
    point p (relative to the center):  [p_z, p_z - min_z, |p_xy|, |<p_xy, a_1>|, |<p_xy, a_2>|]
    edge p -> q, d = q - p:            [|d|, d_z, |d_xy|, <u_p, d_xy>, (u_p x d_xy)_z]
with u_p = p_xy / |p_xy| and a_1, a_2 the principal horizontal axes of the node's points (their
sign is arbitrary, hence the absolute values). The axes tell the long side of a table from its
short side, which the radius alone cannot; min_z (the node's lowest point) is a height reference
that moves less than the center when only part of an object is seen. Translating or rotating
the node about z leaves all of them unchanged (and the context uses distances and heights
only), so Z and F are invariant to a global 4-DoF transform, like the GNN.

Public API:
    ShapeConfig
    sample_node_points(points, k, rng) -> (n, k, 3) float32, (n, k) bool   (numpy, vectorised)
    ShapeEncoder(cfg)(local, valid) -> F (n, d_shape), H (n, K, 2 d_hidden)
    PointEncoder(cfg, d_node)(local, valid, H, F, centers, x) -> Z (n, K, d_z)
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
from torch import nn

from .layers import SinusoidalEmbedding, mlp


@dataclass
class ShapeConfig:
    """points_per_node: K_p, points sampled per node (fewer when the node has fewer).
    knn:        neighbours per point in the edge convolutions.
    d_hidden:   width of the edge convolutions.
    d_z:        per-point feature size (peers recompute Z from the points they receive).
    d_shape:    node shape feature size F.
    context_nodes: nearest other nodes that give each point its context (0: none, ablation).
    d_geo / context_periods: sinusoidal embedding of point-to-node distances (m).
    sample_seed: point-sampling seed used by encode(), so it is deterministic."""

    points_per_node: int = 64
    knn: int = 8
    d_hidden: int = 48
    d_z: int = 32
    d_shape: int = 32
    context_nodes: int = 8
    d_geo: int = 16
    context_periods: tuple[float, float] = (0.25, 20.0)
    sample_seed: int = 0


POINT_FEATS = 5
EDGE_FEATS = 5


def sample_node_points(points: list[np.ndarray], k: int,
                       rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Uniform sample without replacement of up to k points per node, padded.

    Node clouds are voxel-downsampled upstream, so uniform index sampling is close to uniform
    in space. The chosen indices depend only on the point counts and rng, never on coordinates.
    """
    n = len(points)
    counts = np.fromiter(map(len, points), dtype=np.int64, count=n)
    out = np.zeros((n, k, 3), dtype=np.float32)
    valid = np.zeros((n, k), dtype=bool)
    if counts.sum() == 0:
        return out, valid
    flat = np.concatenate([np.asarray(p, dtype=np.float32).reshape(-1, 3) for p in points])
    node = np.repeat(np.arange(n), counts)
    order = np.lexsort((rng.random(len(flat)), node))  # random order within each node
    rank = np.arange(len(flat)) - np.repeat(np.cumsum(counts) - counts, counts)
    keep = rank < k
    out[node[keep], rank[keep]] = flat[order[keep]]
    valid[node[keep], rank[keep]] = True
    return out, valid


def invariant_point_features(local: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """local (n, K, 3), valid (n, K) -> (n, K, 5) yaw-invariant point features."""
    w = valid.unsqueeze(-1).to(local.dtype)
    count = w.sum(1, keepdim=True).clamp_min(1.0)
    xy = local[..., :2]
    centred = (xy - (xy * w).sum(1, keepdim=True) / count) * w
    cov = torch.einsum("nki,nkj->nij", centred, centred) / count
    axes = torch.linalg.eigh(cov + 1e-6 * torch.eye(2)).eigenvectors  # columns: minor, major
    along_axes = torch.einsum("nki,nij->nkj", xy, axes).abs()
    z = local[..., 2]
    z_min = z.masked_fill(~valid, float("inf")).amin(1, keepdim=True)
    z_min = torch.where(torch.isfinite(z_min), z_min, torch.zeros_like(z_min))
    return torch.stack([z, z - z_min, xy.norm(dim=-1), along_axes[..., 1], along_axes[..., 0]], -1)


def invariant_edge_features(local: torch.Tensor, knn_idx: torch.Tensor) -> torch.Tensor:
    """local (n, K, 3), knn_idx (n, K, k) -> (n, K, k, 5) yaw-invariant edge features."""
    u = local[..., :2] / local[..., :2].norm(dim=-1).clamp_min(1e-6).unsqueeze(-1)
    d = _gather_points(local, knn_idx) - local.unsqueeze(2)
    u = u.unsqueeze(2)
    along = (u * d[..., :2]).sum(-1)
    across = u[..., 0] * d[..., 1] - u[..., 1] * d[..., 0]
    return torch.stack([d.norm(dim=-1), d[..., 2], d[..., :2].norm(dim=-1), along, across], -1)


def knn_indices(local: torch.Tensor, valid: torch.Tensor, k: int) -> torch.Tensor:
    """k nearest valid neighbours of every point (self excluded) -> (n, K, k'), k' <= k."""
    dist = torch.cdist(local, local)
    blocked = ~valid.unsqueeze(1) | torch.eye(local.shape[1], dtype=torch.bool)
    dist = dist.masked_fill(blocked, float("inf"))
    return dist.topk(min(k, local.shape[1] - 1), dim=-1, largest=False).indices


class EdgeConv(nn.Module):
    """h_p = MLP(max_q ReLU(W [f_p || f_q || g_pq])) over the kNN q of p (DGCNN-style).

    W is split into per-point parts (applied to the n*K points, then gathered) and an edge
    part, and the MLP runs after the max, so the per-edge work is one small Linear."""

    def __init__(self, d_point: int, d_edge: int, d_out: int, neighbour_feats: bool):
        super().__init__()
        self.point_lin = nn.Linear(d_point, d_out)
        self.neighbour_lin = nn.Linear(d_point, d_out, bias=False) if neighbour_feats else None
        self.edge_lin = nn.Linear(d_edge, d_out, bias=False)
        self.out = nn.Linear(d_out, d_out)

    def forward(self, f, knn, edge, edge_ok):
        """f (n, K, d), knn (n, K, k), edge (n, K, k, d_e), edge_ok (n, K, k) -> (n, K, d_out)."""
        h = self.point_lin(f).unsqueeze(2) + self.edge_lin(edge)
        if self.neighbour_lin is not None:
            h = h + _gather_points(self.neighbour_lin(f), knn)
        return torch.relu(self.out(_masked_max(torch.relu(h), edge_ok, dim=2)))


class ShapeEncoder(nn.Module):
    """One node at a time: per-point local features H and the node shape feature F."""

    def __init__(self, cfg: ShapeConfig):
        super().__init__()
        self.cfg = cfg
        h = cfg.d_hidden
        self.conv1 = EdgeConv(POINT_FEATS, EDGE_FEATS, h, neighbour_feats=False)
        self.conv2 = EdgeConv(h, EDGE_FEATS, h, neighbour_feats=True)
        self.node_head = mlp([2 * h, 2 * h, cfg.d_shape])

    def forward(self, local: torch.Tensor, valid: torch.Tensor):
        """local (n, K, 3) points minus node center, valid (n, K) -> F (n, d_s), H (n, K, 2h)."""
        n, num_pts, _ = local.shape
        if num_pts < 2:
            return local.new_zeros(n, self.cfg.d_shape), local.new_zeros(n, num_pts, 2 * self.cfg.d_hidden)
        knn = knn_indices(local, valid, self.cfg.knn)
        # a point with fewer valid neighbours than k sees padding: mask those edges out
        edge_ok = _gather_points(valid.unsqueeze(-1), knn).squeeze(-1)
        point = invariant_point_features(local, valid)
        edge = invariant_edge_features(local, knn)
        h1 = self.conv1(point, knn, edge, edge_ok)
        h2 = self.conv2(h1, knn, edge, edge_ok)
        hidden = torch.cat([h1, h2], dim=-1) * valid.unsqueeze(-1)
        return self.node_head(_masked_max(hidden, valid, dim=1)), hidden


class PointEncoder(nn.Module):
    """Z_p = MLP[H_p || F || C_p]: local shape, the node's shape, and context C_p.

    C_p places the point among the `context_nodes` nearest other nodes j (by center distance):
    C_p = max_j ReLU(W_g [psi(|p - o_j|) || p_z - o_j,z] + W_x x_j), with x_j their node
    descriptors. A node's own points cannot tell its two symmetric sides apart (a chair's
    left and right); which side faces the table can. Distances and heights only: invariant."""

    def __init__(self, cfg: ShapeConfig, d_node: int):
        super().__init__()
        self.cfg = cfg
        h = cfg.d_hidden
        self.psi = SinusoidalEmbedding(cfg.d_geo, *cfg.context_periods)
        self.geo = nn.Linear(cfg.d_geo + 1, h)
        self.node = nn.Linear(d_node, h, bias=False)
        self.context_out = nn.Linear(h, h)
        self.head = mlp([2 * h + cfg.d_shape + h, 2 * h, cfg.d_z], norm=False)

    def context(self, local, centers, x):
        n, num_pts, _ = local.shape
        m = min(self.cfg.context_nodes, n - 1)
        if m < 1:
            return local.new_zeros(n, num_pts, self.cfg.d_hidden)
        dist = torch.cdist(centers, centers).fill_diagonal_(float("inf"))
        nearest = dist.topk(m, dim=1, largest=False).indices  # (n, m)
        offset = centers.unsqueeze(1) - centers[nearest]  # o_i - o_j, (n, m, 3)
        d = local.unsqueeze(2) + offset.unsqueeze(1)  # p - o_j, (n, K, m, 3)
        geo = self.geo(torch.cat([self.psi(d.norm(dim=-1)), d[..., 2:]], dim=-1))
        h = torch.relu(geo + self.node(x)[nearest].unsqueeze(1))
        return torch.relu(self.context_out(h.amax(dim=2)))

    def forward(self, local, valid, hidden, shape, centers, x):
        """local, valid, hidden from ShapeEncoder; shape F (n, d_s); centers (n, 3) node centers;
        x (n, d) node descriptors -> Z (n, K, d_z), zero at padding."""
        num_pts = local.shape[1]
        ctx = self.context(local, centers, x)
        z = self.head(torch.cat([hidden, shape.unsqueeze(1).expand(-1, num_pts, -1), ctx], -1))
        return z * valid.unsqueeze(-1)


def _gather_points(f: torch.Tensor, knn: torch.Tensor) -> torch.Tensor:
    """f (n, K, d), knn (n, K, k) -> f of each neighbour (n, K, k, d)."""
    n, num_pts, k = knn.shape
    flat = knn.reshape(n, num_pts * k, 1).expand(-1, -1, f.shape[-1])
    return torch.gather(f, 1, flat).view(n, num_pts, k, f.shape[-1])


def _masked_max(x: torch.Tensor, mask: torch.Tensor, dim: int) -> torch.Tensor:
    """Max over `dim` of the non-negative (post-ReLU) x where mask holds; 0 where none does."""
    return (x * mask.unsqueeze(-1)).amax(dim=dim)
