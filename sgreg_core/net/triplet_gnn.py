"""Triplet-boosted GNN (paper section IV-C): each node attends over triplets of its neighbours.

For anchor i and two neighbours (j, k) the triplet is ordered anticlockwise about z (the sign
of (e_ij x e_ik)_z, unchanged by yaw and translation) and described by
    t_ijk = [x_j || x_k || psi_L(|e_ij|) || psi_L(|e_ik|) || psi_A(angle(e_ij, e_ik))].
The anchor attends over its triplets, m_i = Attn(x_i, {t_ijk}), and updates residually:
x_i <- x_i + MLP[x_i || m_i]. Only lengths, angles and the z-orientation enter, so the output is
invariant to any global 4-DoF transform by construction.

With use_triplets=False (the paper's ablation) the units are single neighbours
t_ij = [x_j || psi_L(|e_ij|)]: plain graph attention.

Everything is batched as padded (n, T) index tensors; no loop over nodes or triplets.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import nn

from .layers import SinusoidalEmbedding, mlp


@dataclass
class GNNConfig:
    """layers:        attention rounds (units are rebuilt from the current x each round).
    heads:          attention heads.
    use_triplets:   False = ablation, attend over single neighbours instead of triplets.
    max_neighbors:  an anchor keeps its nearest neighbours only (walls can have dozens).
    max_triplets:   triplets sampled per anchor among its neighbour pairs.
    d_geo:          size of each sinusoidal embedding psi_L / psi_A.
    dist_periods:   shortest / longest period (m) of psi_L.
    angle_periods:  shortest / longest period (rad) of psi_A.
    eval_seed:      triplet sampling seed in eval mode, so encode() is deterministic."""

    layers: int = 2
    heads: int = 4
    use_triplets: bool = True
    max_neighbors: int = 12
    max_triplets: int = 16
    d_geo: int = 16
    dist_periods: tuple[float, float] = (0.5, 20.0)
    angle_periods: tuple[float, float] = (0.5, 4.0 * math.pi)
    eval_seed: int = 0


def neighbor_table(centers: torch.Tensor, edges: torch.Tensor,
                   max_neighbors: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Padded nearest-first neighbour lists: (n, D) indices and (n, D) validity, D <= max."""
    n = centers.shape[0]
    if edges.numel() == 0:
        return (torch.zeros(n, 0, dtype=torch.long), torch.zeros(n, 0, dtype=torch.bool))
    src = torch.cat([edges[:, 0], edges[:, 1]])
    dst = torch.cat([edges[:, 1], edges[:, 0]])
    # sort by (src, distance): stable sort on the minor key first
    order = torch.argsort((centers[dst] - centers[src]).norm(dim=-1), stable=True)
    order = order[torch.argsort(src[order], stable=True)]
    src, dst = src[order], dst[order]
    counts = torch.bincount(src, minlength=n)
    rank = torch.arange(src.numel()) - (torch.cumsum(counts, 0) - counts)[src]
    keep = rank < max_neighbors
    width = int(min(int(counts.max()), max_neighbors))
    nbr = torch.zeros(n, width, dtype=torch.long)
    valid = torch.zeros(n, width, dtype=torch.bool)
    nbr[src[keep], rank[keep]] = dst[keep]
    valid[src[keep], rank[keep]] = True
    return nbr, valid


def sample_triplets(nbr: torch.Tensor, valid: torch.Tensor, max_triplets: int,
                    generator: torch.Generator | None = None):
    """Sample up to max_triplets neighbour pairs (j, k) per anchor -> j, k, mask, each (n, T)."""
    n, width = nbr.shape
    if width < 2 or max_triplets < 1:
        empty = torch.zeros(n, 0, dtype=torch.long)
        return empty, empty, torch.zeros(n, 0, dtype=torch.bool)
    pairs = torch.combinations(torch.arange(width), 2)  # (C, 2)
    ok = valid[:, pairs[:, 0]] & valid[:, pairs[:, 1]]
    # a random key per candidate, -1 for impossible ones: top-T keys = uniform sample of valid
    keys = torch.rand(ok.shape, generator=generator).masked_fill(~ok, -1.0)
    top, idx = keys.topk(min(max_triplets, pairs.shape[0]), dim=1)
    chosen = pairs[idx]
    return nbr.gather(1, chosen[..., 0]), nbr.gather(1, chosen[..., 1]), top >= 0


def order_anticlockwise(centers: torch.Tensor, j: torch.Tensor, k: torch.Tensor):
    """Swap (j, k) where k is clockwise of j as seen from anchor i (row index) about +z."""
    anchor = centers.unsqueeze(1)
    e_ij, e_ik = centers[j] - anchor, centers[k] - anchor
    swap = (e_ij[..., 0] * e_ik[..., 1] - e_ij[..., 1] * e_ik[..., 0]) < 0
    return torch.where(swap, k, j), torch.where(swap, j, k)


class ContextAttention(nn.Module):
    """x_i attends over its context units, then x_i <- x_i + MLP[x_i || m_i]."""

    def __init__(self, d: int, d_unit: int, heads: int):
        super().__init__()
        if d % heads:
            raise ValueError(f"node dim {d} is not divisible by {heads} heads")
        self.heads = heads
        self.q = nn.Linear(d, d)
        self.kv = nn.Linear(d_unit, 2 * d)
        self.out = nn.Linear(d, d)
        self.update = mlp([2 * d, 2 * d, d])

    def forward(self, x: torch.Tensor, units: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        n, t, _ = units.shape
        h, dh = self.heads, x.shape[1] // self.heads
        q = self.q(x).view(n, h, dh)
        k, v = self.kv(units).view(n, t, 2, h, dh).unbind(2)
        logits = torch.einsum("nhd,nthd->nht", q, k) / math.sqrt(dh)
        # masked units get a huge negative logit and are zeroed after the softmax, so an
        # anchor without any unit receives m_i = 0 (no NaN from an all -inf row)
        logits = logits.masked_fill(~mask.unsqueeze(1), -1e9)
        attn = torch.softmax(logits, dim=-1) * mask.unsqueeze(1)
        m = self.out(torch.einsum("nht,nthd->nhd", attn, v).reshape(n, h * dh))
        return x + self.update(torch.cat([x, m], dim=-1))


class TripletGNN(nn.Module):
    def __init__(self, cfg: GNNConfig, d: int):
        super().__init__()
        self.cfg = cfg
        self.psi_l = SinusoidalEmbedding(cfg.d_geo, *cfg.dist_periods)
        self.psi_a = SinusoidalEmbedding(cfg.d_geo, *cfg.angle_periods)
        d_unit = 2 * d + 3 * cfg.d_geo if cfg.use_triplets else d + cfg.d_geo
        self.layers = nn.ModuleList(ContextAttention(d, d_unit, cfg.heads)
                                    for _ in range(cfg.layers))

    def context(self, centers: torch.Tensor, edges: torch.Tensor):
        """Per anchor: member indices (one or two (n, T) tensors), mask (n, T), geometry (n, T, g)."""
        nbr, valid = neighbor_table(centers, edges, self.cfg.max_neighbors)
        anchor = centers.unsqueeze(1)
        if not self.cfg.use_triplets:
            return (nbr,), valid, self.psi_l((centers[nbr] - anchor).norm(dim=-1))
        generator = None
        if not self.training:
            generator = torch.Generator().manual_seed(self.cfg.eval_seed)
        j, k, mask = sample_triplets(nbr, valid, self.cfg.max_triplets, generator)
        j, k = order_anticlockwise(centers, j, k)
        e_ij, e_ik = centers[j] - anchor, centers[k] - anchor
        l_ij, l_ik = e_ij.norm(dim=-1), e_ik.norm(dim=-1)
        cos = (e_ij * e_ik).sum(-1) / (l_ij * l_ik).clamp_min(1e-6)
        angle = torch.acos(cos.clamp(-1.0, 1.0))
        geo = torch.cat([self.psi_l(l_ij), self.psi_l(l_ik), self.psi_a(angle)], dim=-1)
        return (j, k), mask, geo

    def forward(self, x0: torch.Tensor, centers: torch.Tensor, edges: torch.Tensor) -> torch.Tensor:
        """x0 (n, d), centers (n, 3), edges (m, 2) -> x1 (n, d)."""
        members, mask, geo = self.context(centers, edges)
        x = x0
        for layer in self.layers:
            units = torch.cat([x[idx] for idx in members] + [geo], dim=-1)
            x = layer(x, units, mask)
        return x
