"""Small building blocks shared by the network modules."""
from __future__ import annotations

import math

import torch
from torch import nn


def mlp(dims: list[int], final_activation: bool = False, norm: bool = True) -> nn.Sequential:
    """Linear layers with (LayerNorm +) ReLU between them (and after the last if asked).

    norm=False for per-point / per-edge MLPs, where LayerNorm costs more than the Linear."""
    layers: list[nn.Module] = []
    for k, (d_in, d_out) in enumerate(zip(dims[:-1], dims[1:])):
        layers.append(nn.Linear(d_in, d_out))
        if k < len(dims) - 2 or final_activation:
            layers += [nn.LayerNorm(d_out)] if norm else []
            layers.append(nn.ReLU(inplace=True))
    return nn.Sequential(*layers)


class SinusoidalEmbedding(nn.Module):
    """psi(x) = [sin(2 pi x / p_k), cos(2 pi x / p_k)] for periods p_k spaced geometrically.

    Periods span [min_period, max_period] so that both fine and coarse differences of a scalar
    (a distance in metres, an angle in radians) stay distinguishable. No parameters.
    """

    def __init__(self, dim: int, min_period: float, max_period: float):
        super().__init__()
        if dim % 2:
            raise ValueError(f"embedding dim must be even, got {dim}")
        periods = torch.logspace(math.log10(min_period), math.log10(max_period), dim // 2)
        self.register_buffer("freq", 2.0 * math.pi / periods, persistent=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        phase = x.unsqueeze(-1) * self.freq
        return torch.cat([phase.sin(), phase.cos()], dim=-1)
