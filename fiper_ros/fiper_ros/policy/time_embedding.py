"""Sinusoidal embedding of the flow time ``s`` / diffusion step ``r`` shared by both backbones."""
from __future__ import annotations

import math

import torch
from torch import nn


class SinusoidalEmbedding(nn.Module):
    """``[N]`` scalar times -> ``[N, dim]`` sin/cos features (transformer positional-encoding style)."""

    def __init__(self, dim: int, scale: float = 1.0) -> None:
        super().__init__()
        if dim % 2:
            raise ValueError(f"embedding dim must be even, got {dim}")
        half = dim // 2
        self.register_buffer("frequencies", torch.exp(-math.log(10000.0) * torch.arange(half) / max(half - 1, 1)))
        self.scale = scale

    def forward(self, t: torch.Tensor) -> torch.Tensor:
        """Features of the times ``t``."""
        angles = (t.float() * self.scale)[:, None] * self.frequencies[None, :]
        return torch.cat([angles.sin(), angles.cos()], dim=-1)
