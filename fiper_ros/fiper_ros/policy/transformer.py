"""ACT-style transformer backbone of the flow-matching policy (Sorting, Stacking).

Token sequence ``[observation, time, a_0 ... a_{H-1}]``; a pre-norm transformer encoder mixes them and
the action tokens are read out as the velocity ``v(A^s, O^e, s)`` of every chunk step.
"""
from __future__ import annotations

import torch
from torch import nn

from .time_embedding import SinusoidalEmbedding


class ChunkTransformer(nn.Module):
    """Velocity network ``(A^s [N, H, D], O^e [N, E], s [N]) -> [N, H, D]``."""

    def __init__(self, action_dim: int, horizon: int, cond_dim: int, width: int = 128, layers: int = 3,
                 heads: int = 4) -> None:
        super().__init__()
        self.action_in = nn.Linear(action_dim, width)
        self.cond_in = nn.Linear(cond_dim, width)
        self.time_in = nn.Sequential(SinusoidalEmbedding(width, scale=100.0), nn.Linear(width, width), nn.Mish(),
                                     nn.Linear(width, width))
        self.position = nn.Parameter(torch.zeros(1, horizon + 2, width))
        nn.init.normal_(self.position, std=0.02)
        layer = nn.TransformerEncoderLayer(width, heads, dim_feedforward=4 * width, dropout=0.0,
                                           activation="gelu", batch_first=True, norm_first=True)
        self.encoder = nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)
        self.out = nn.Sequential(nn.LayerNorm(width), nn.Linear(width, action_dim))
        self.horizon = horizon

    def forward(self, actions: torch.Tensor, cond: torch.Tensor, time: torch.Tensor) -> torch.Tensor:
        """Predicted velocity for every chunk step."""
        tokens = torch.cat([self.cond_in(cond)[:, None], self.time_in(time)[:, None], self.action_in(actions)], dim=1)
        hidden = self.encoder(tokens + self.position)
        return self.out(hidden[:, 2:])
