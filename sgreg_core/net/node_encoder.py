"""Node encoding x0_i = [TextEncoder(s_i) || MLP_b(b_i)] (paper section IV-B)."""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from .layers import mlp
from .text import TEXT_DIM


@dataclass
class NodeEncoderConfig:
    """d_text: the 384-d MiniLM embedding is projected to this size (keeps the GNN small).
    d_box:  output size of the box-extent MLP.
    min_extent: extents are clamped below (metres) before the log, so flat walls stay finite."""

    d_text: int = 96
    d_box: int = 32
    min_extent: float = 0.02

    @property
    def d_out(self) -> int:
        return self.d_text + self.d_box


class NodeEncoder(nn.Module):
    def __init__(self, cfg: NodeEncoderConfig):
        super().__init__()
        self.cfg = cfg
        self.text_proj = nn.Linear(TEXT_DIM, cfg.d_text)
        self.box_mlp = mlp([3, cfg.d_box, cfg.d_box])

    def forward(self, text: torch.Tensor, extents: torch.Tensor) -> torch.Tensor:
        """text (n, 384), extents (n, 3) metres -> x0 (n, d_text + d_box)."""
        # log-extents: object sizes span two orders of magnitude (cup .. wall)
        box = self.box_mlp(extents.clamp_min(self.cfg.min_extent).log())
        return torch.cat([self.text_proj(text), box], dim=-1)
