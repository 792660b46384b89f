"""Training losses (paper section V): L = L_gnn + L_shape.

L_gnn:   -log A_ij over ground-truth node pairs (dual-softmax node matching).
L_shape: an InfoNCE contrastive loss on the node shape features F (the matched node in the
         other view is the positive, every other node a negative), plus the optimal-transport
         loss on point features: -log P over ground-truth point pairs (mutual nearest, closer
         than pos_radius in the common frame) and -log P[., dustbin] for points with no
         counterpart within neg_radius; points in between are ambiguous and left out.

Public API:
    LossConfig
    node_match_loss(log_a, gt) -> scalar
    shape_contrastive_loss(f_src, f_ref, gt, temperature) -> scalar
    point_gt(pts_src, valid_src, pts_ref, valid_ref, pos_radius, neg_radius) -> PointTargets
    point_match_loss(log_p, targets) -> scalar
    pair_losses(model, inp_src, inp_ref, T_src_ref, gt, cfg) -> {"total", "gnn", "contrastive", "ot"}
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from .matching import log_dual_softmax
from .model import GraphInput, SGRegModel


@dataclass
class LossConfig:
    """w_*: weights of L_gnn, the shape contrastive term and the OT term.
    temperature: InfoNCE temperature on unit-norm shape features.
    pos_radius / neg_radius (m): point pair positive below / dustbin target above.
    min_iou: ground-truth node pairs used for every term have IoU >= this."""

    w_gnn: float = 1.0
    w_contrastive: float = 0.5
    w_ot: float = 1.0
    temperature: float = 0.1
    pos_radius: float = 0.05
    neg_radius: float = 0.15
    min_iou: float = 0.3


def node_match_loss(log_a: torch.Tensor, gt: torch.Tensor) -> torch.Tensor:
    """log_a (n_src, n_ref) log dual-softmax, gt (m, 2) node index pairs -> mean -log A."""
    if gt.shape[0] == 0:
        return log_a.sum() * 0.0
    return -log_a[gt[:, 0], gt[:, 1]].mean()


def shape_contrastive_loss(f_src: torch.Tensor, f_ref: torch.Tensor, gt: torch.Tensor,
                           temperature: float) -> torch.Tensor:
    """Symmetric InfoNCE: each gt src node must pick its partner among all ref nodes and back."""
    if gt.shape[0] == 0:
        return (f_src.sum() + f_ref.sum()) * 0.0
    logits = F.normalize(f_src, dim=-1) @ F.normalize(f_ref, dim=-1).T / temperature
    rows = logits.log_softmax(dim=1)[gt[:, 0], gt[:, 1]]
    cols = logits.log_softmax(dim=0)[gt[:, 0], gt[:, 1]]
    return -(rows.mean() + cols.mean()) / 2


@dataclass
class PointTargets:
    """Per matched node pair (B of them), boolean targets over the (K+1, K+1) transport plan."""

    positive: torch.Tensor    # (B, K, K) point pairs
    dustbin_src: torch.Tensor  # (B, K) src points that should go to the dustbin
    dustbin_ref: torch.Tensor  # (B, K) ref points that should go to the dustbin

    @property
    def count(self) -> int:
        return int(self.positive.sum() + self.dustbin_src.sum() + self.dustbin_ref.sum())


def point_gt(pts_src: torch.Tensor, valid_src: torch.Tensor, pts_ref: torch.Tensor,
             valid_ref: torch.Tensor, pos_radius: float, neg_radius: float) -> PointTargets:
    """pts (B, K, 3) in a common frame (src already moved by the gt transform)."""
    dist = torch.cdist(pts_src, pts_ref)
    dist = dist.masked_fill(~(valid_src.unsqueeze(2) & valid_ref.unsqueeze(1)), float("inf"))
    nearest_ref = dist.min(dim=2, keepdim=True).values
    nearest_src = dist.min(dim=1, keepdim=True).values
    positive = (dist < pos_radius) & (dist <= nearest_ref) & (dist <= nearest_src)
    return PointTargets(positive=positive,
                        dustbin_src=valid_src & (nearest_ref.squeeze(2) > neg_radius),
                        dustbin_ref=valid_ref & (nearest_src.squeeze(1) > neg_radius))


def point_match_loss(log_p: torch.Tensor, targets: PointTargets) -> torch.Tensor:
    """Mean -log P over positive pairs and dustbin assignments (SuperGlue-style)."""
    count = targets.count
    if count == 0:
        return log_p.sum() * 0.0
    total = (log_p[:, :-1, :-1][targets.positive].sum()
             + log_p[:, :-1, -1][targets.dustbin_src].sum()
             + log_p[:, -1, :-1][targets.dustbin_ref].sum())
    return -total / count


def pair_losses(model: SGRegModel, inp_src: GraphInput, inp_ref: GraphInput,
                T_src_ref: torch.Tensor, gt: torch.Tensor, cfg: LossConfig) -> dict[str, torch.Tensor]:
    """All loss terms of one registration pair; gt (m, 2) node index pairs (src, ref)."""
    out_src, out_ref = model(inp_src), model(inp_ref)
    l_gnn = node_match_loss(log_dual_softmax(out_src.descriptor, out_ref.descriptor), gt)
    l_con = shape_contrastive_loss(out_src.shape, out_ref.shape, gt, cfg.temperature)

    if gt.shape[0] == 0:     # no node pair at the loss's IoU to match points in: the pair adds nothing
        l_ot = (out_src.z.sum() + out_ref.z.sum()) * 0.0
    else:
        ia, ib = gt[:, 0], gt[:, 1]
        moved = inp_src.points[ia] @ T_src_ref[:3, :3].T + T_src_ref[:3, 3]
        targets = point_gt(moved, inp_src.valid[ia], inp_ref.points[ib], inp_ref.valid[ib],
                           cfg.pos_radius, cfg.neg_radius)
        log_p = model.point_matcher.log_transport(out_src.z[ia], inp_src.valid[ia],
                                                  out_ref.z[ib], inp_ref.valid[ib])
        l_ot = point_match_loss(log_p, targets)
    total = cfg.w_gnn * l_gnn + cfg.w_contrastive * l_con + cfg.w_ot * l_ot
    return {"total": total, "gnn": l_gnn, "contrastive": l_con, "ot": l_ot}
