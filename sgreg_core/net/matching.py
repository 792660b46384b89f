"""Hierarchical matching (paper section IV-E): nodes by dual softmax, then points by Sinkhorn.

Nodes: S = <W x_i, W x_j> / sqrt(d), A = softmax_rows(S) * softmax_cols(S); a pair is a match
when A > threshold and it is a mutual top-k. The projection W is applied by the sender (the
descriptor is what a coarse message carries), so matching itself needs no weights.

Points: for every matched node pair at once, S_p = s * cos(Z_i, Z_j) with a learnable scale s
(unit-norm point features learn much faster than raw dot products here), padded with a
learnable dustbin row/column and solved as optimal transport by Sinkhorn (in the log domain
while training, on scaling vectors at inference: the same iterations, several times faster);
mutual top-k entries above a threshold are the point correspondences.

Public API:
    MatchConfig
    mutual_topk(scores, k) -> bool mask           (..., n, m): top-k in its row and its column
    log_dual_softmax(desc_src, desc_ref) -> (n_src, n_ref)    log A
    log_optimal_transport(scores, valid_src, valid_ref, dustbin, iters) -> (B, n_src+1, n_ref+1) log P
    NodeMatcher(d_in, cfg): descriptor(x), match(desc_src, desc_ref) -> (i_src, i_ref, confidence)
    PointMatcher(cfg): log_transport(z_src, valid_src, z_ref, valid_ref),
                       match(...) -> (pair, i_src, i_ref, p)

Rows are the source graph's, columns the reference graph's (the pipeline's SRC -> REF).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

# finite stand-in for log(0): -inf would turn Sinkhorn's padded rows into NaN
LOG_ZERO = -1e9


@dataclass
class MatchConfig:
    """d_match:         node descriptor size (what a coarse message carries per node).
    node_threshold:  minimum dual-softmax confidence A_ij of a node match.
    node_topk:       a node match must be in the top-k of its row and of its column (3: in
                     maps that share few objects the right match is often a node's second or
                     third choice, and the pose estimator's cliques and the verdict sort them
                     out; docs/RESULTS.md, session 18).
    sinkhorn_iters:  Sinkhorn iterations (log domain in training, scaling vectors at inference).
    point_threshold: minimum transport mass (rows sum to 1) of a point correspondence.
    point_topk:      mutual top-k for point correspondences."""

    d_match: int = 64
    node_threshold: float = 0.05
    node_topk: int = 3
    sinkhorn_iters: int = 20
    point_threshold: float = 0.1
    point_topk: int = 1

    def __post_init__(self):
        # a threshold of 0 keeps every mutual top-k entry (log 0: no bound)
        if not (0.0 <= self.node_threshold < 1.0 and 0.0 <= self.point_threshold < 1.0):
            raise ValueError(f"match: node_threshold and point_threshold must lie in [0, 1), got "
                             f"{self.node_threshold} and {self.point_threshold}")
        if not (self.d_match >= 1 and self.node_topk >= 1 and self.point_topk >= 1 and self.sinkhorn_iters >= 1):
            raise ValueError("match: d_match, node_topk, point_topk and sinkhorn_iters must be >= 1")


def _log_bound(threshold: float) -> float:
    return math.log(threshold) if threshold > 0 else -math.inf


def mutual_topk(scores: torch.Tensor, k: int) -> torch.Tensor:
    """True where an entry is among the k largest of its row and of its column."""
    kr, kc = min(k, scores.shape[-1]), min(k, scores.shape[-2])
    row = torch.zeros_like(scores, dtype=torch.bool).scatter(-1, scores.topk(kr, -1).indices, True)
    col = torch.zeros_like(scores, dtype=torch.bool).scatter(-2, scores.topk(kc, -2).indices, True)
    return row & col


def log_dual_softmax(desc_src: torch.Tensor, desc_ref: torch.Tensor) -> torch.Tensor:
    """log A = log_softmax_rows(S) + log_softmax_cols(S), S = <a_i, b_j> / sqrt(d)."""
    s = desc_src @ desc_ref.T / math.sqrt(desc_src.shape[-1])
    return s.log_softmax(dim=1) + s.log_softmax(dim=0)


def log_optimal_transport(scores: torch.Tensor, valid_src: torch.Tensor, valid_ref: torch.Tensor,
                          dustbin: torch.Tensor, iters: int) -> torch.Tensor:
    """Entropic OT with a dustbin, batched: scores (B, n_src, n_ref) -> log P (B, n_src+1, n_ref+1).

    Each valid point carries mass 1, each dustbin the other side's point count (so that every
    point may go unmatched); padded points carry none. Rows of valid points sum to 1 in P.
    """
    batch, n_src, n_ref = scores.shape
    bins_src = dustbin.expand(batch, n_src, 1)
    bins_ref = dustbin.expand(batch, 1, n_ref)
    corner = dustbin.expand(batch, 1, 1)
    couplings = torch.cat([torch.cat([scores, bins_src], -1), torch.cat([bins_ref, corner], -1)], 1)
    true_ = valid_src.new_ones(batch, 1)
    rows = torch.cat([valid_src, true_], 1)
    cols = torch.cat([valid_ref, true_], 1)
    couplings = couplings.masked_fill(~(rows.unsqueeze(2) & cols.unsqueeze(1)), LOG_ZERO)

    count_src = valid_src.sum(1, keepdim=True).clamp_min(1).to(scores.dtype)
    count_ref = valid_ref.sum(1, keepdim=True).clamp_min(1).to(scores.dtype)
    norm = -(count_src + count_ref).log()
    log_mu = torch.cat([norm.expand(-1, n_src).masked_fill(~valid_src, LOG_ZERO), count_ref.log() + norm], 1)
    log_nu = torch.cat([norm.expand(-1, n_ref).masked_fill(~valid_ref, LOG_ZERO), count_src.log() + norm], 1)

    valid = couplings > LOG_ZERO / 2
    spread = (couplings.masked_fill(~valid, -math.inf).amax() - couplings.masked_fill(~valid, math.inf).amin())
    if not torch.is_grad_enabled() and float(spread) < 60.0:   # exp stays well inside float32
        return _sinkhorn_scaling(couplings, log_mu, log_nu, iters) - norm.unsqueeze(2)
    u, v = torch.zeros_like(log_mu), torch.zeros_like(log_nu)
    for _ in range(iters):
        u = log_mu - torch.logsumexp(couplings + v.unsqueeze(1), dim=2)
        v = log_nu - torch.logsumexp(couplings + u.unsqueeze(2), dim=1)
    return couplings + u.unsqueeze(2) + v.unsqueeze(1) - norm.unsqueeze(2)


def _sinkhorn_scaling(couplings: torch.Tensor, log_mu: torch.Tensor, log_nu: torch.Tensor,
                      iters: int) -> torch.Tensor:
    """The same iterations as the log-domain loop, on scaling vectors a = e^u, b = e^v: two
    batched mat-vecs per iteration instead of two logsumexps over the whole (B, K+1, K+1)
    tensor (about 10x faster on a CPU). Without gradients only: the scores are bounded
    (cosines times a learnt scale: about 18 with the shipped weights), shifting each batch by
    its maximum keeps exp finite, and the caller falls back to the log domain when the scores
    spread over more than 60 (e^-60 is still far above float32's smallest normal); the shift
    cancels in a_i K_ij b_j."""
    c = couplings - couplings.amax(dim=(1, 2), keepdim=True)
    K = c.exp()
    mu, nu = log_mu.exp(), log_nu.exp()
    b = torch.ones_like(nu)
    tiny = torch.finfo(K.dtype).tiny
    for _ in range(iters):
        a = mu / torch.bmm(K, b.unsqueeze(2)).squeeze(2).clamp_min(tiny)
        b = nu / torch.bmm(K.transpose(1, 2), a.unsqueeze(2)).squeeze(2).clamp_min(tiny)
    return c + a.clamp_min(tiny).log().unsqueeze(2) + b.clamp_min(tiny).log().unsqueeze(1)


class NodeMatcher(nn.Module):
    def __init__(self, d_in: int, cfg: MatchConfig):
        super().__init__()
        self.cfg = cfg
        self.proj = nn.Linear(d_in, cfg.d_match)

    def descriptor(self, x: torch.Tensor) -> torch.Tensor:
        return self.proj(x)

    def match(self, desc_src: torch.Tensor, desc_ref: torch.Tensor):
        """-> index in src, index in ref, confidence A_ij of every node match."""
        if desc_src.shape[0] == 0 or desc_ref.shape[0] == 0:
            empty = torch.zeros(0, dtype=torch.long)
            return empty, empty, torch.zeros(0)
        log_A = log_dual_softmax(desc_src, desc_ref)
        keep = mutual_topk(log_A, self.cfg.node_topk) & (log_A > _log_bound(self.cfg.node_threshold))
        i_src, i_ref = keep.nonzero(as_tuple=True)
        return i_src, i_ref, log_A[i_src, i_ref].exp()


class PointMatcher(nn.Module):
    def __init__(self, cfg: MatchConfig):
        super().__init__()
        self.cfg = cfg
        self.dustbin = nn.Parameter(torch.tensor(1.0))
        self.log_scale = nn.Parameter(torch.tensor(math.log(10.0)))

    def log_transport(self, z_src, valid_src, z_ref, valid_ref) -> torch.Tensor:
        """Per matched node pair: z (B, K, d_z), valid (B, K) -> log P (B, K+1, K+1)."""
        cos = torch.einsum("bkd,bld->bkl", F.normalize(z_src, dim=-1), F.normalize(z_ref, dim=-1))
        scores = cos * self.log_scale.exp()
        return log_optimal_transport(scores, valid_src, valid_ref, self.dustbin, self.cfg.sinkhorn_iters)

    def match(self, z_src, valid_src, z_ref, valid_ref):
        """-> pair index, point index in src, point index in ref, transport mass of each match."""
        if z_src.shape[0] == 0:
            empty = torch.zeros(0, dtype=torch.long)
            return empty, empty, empty, torch.zeros(0)
        log_p = self.log_transport(z_src, valid_src, z_ref, valid_ref)[:, :-1, :-1]
        keep = mutual_topk(log_p, self.cfg.point_topk) & (log_p > _log_bound(self.cfg.point_threshold))
        keep &= valid_src.unsqueeze(2) & valid_ref.unsqueeze(1)
        pair, i_src, i_ref = keep.nonzero(as_tuple=True)
        return pair, i_src, i_ref, log_p[pair, i_src, i_ref].exp()
