"""Temporal 1-D U-Net with FiLM conditioning (Diffusion Policy's ``ConditionalUnet1D``, scaled down)."""
from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from .time_embedding import SinusoidalEmbedding


class ConvBlock(nn.Sequential):
    """Conv1d -> GroupNorm -> Mish."""

    def __init__(self, c_in: int, c_out: int, kernel: int) -> None:
        super().__init__(nn.Conv1d(c_in, c_out, kernel, padding=kernel // 2), nn.GroupNorm(8, c_out), nn.Mish())


class FiLMResBlock(nn.Module):
    """Two conv blocks; the condition sets a per-channel scale and bias between them."""

    def __init__(self, c_in: int, c_out: int, cond_dim: int, kernel: int) -> None:
        super().__init__()
        self.block1 = ConvBlock(c_in, c_out, kernel)
        self.block2 = ConvBlock(c_out, c_out, kernel)
        self.film = nn.Sequential(nn.Mish(), nn.Linear(cond_dim, 2 * c_out))
        self.skip = nn.Conv1d(c_in, c_out, 1) if c_in != c_out else nn.Identity()

    def forward(self, x: torch.Tensor, cond: torch.Tensor) -> torch.Tensor:
        """``[N, c_in, L] -> [N, c_out, L]``."""
        scale, bias = self.film(cond)[:, :, None].chunk(2, dim=1)
        return self.block2(self.block1(x) * (1.0 + scale) + bias) + self.skip(x)


class TemporalUnet(nn.Module):
    """Noise network ``(A^r [N, H, D], O^e [N, E], r [N]) -> eps [N, H, D]``; ``H`` divisible by 2^(levels-1)."""

    def __init__(self, action_dim: int, cond_dim: int, channels: Sequence[int] = (64, 128), kernel: int = 5,
                 step_dim: int = 64) -> None:
        super().__init__()
        self.step_in = nn.Sequential(SinusoidalEmbedding(step_dim), nn.Linear(step_dim, 4 * step_dim), nn.Mish(),
                                     nn.Linear(4 * step_dim, step_dim))
        film_dim = step_dim + cond_dim
        widths = [action_dim, *channels]
        self.down = nn.ModuleList()
        for index, (c_in, c_out) in enumerate(zip(widths[:-1], widths[1:])):
            last = index == len(channels) - 1
            self.down.append(nn.ModuleList([FiLMResBlock(c_in, c_out, film_dim, kernel),
                                            FiLMResBlock(c_out, c_out, film_dim, kernel),
                                            nn.Identity() if last else nn.Conv1d(c_out, c_out, 3, 2, 1)]))
        self.mid = nn.ModuleList([FiLMResBlock(channels[-1], channels[-1], film_dim, kernel) for _ in range(2)])
        self.up = nn.ModuleList()
        for c_out, c_in in zip(reversed(channels[:-1]), reversed(channels[1:])):
            self.up.append(nn.ModuleList([FiLMResBlock(2 * c_in, c_out, film_dim, kernel),
                                          FiLMResBlock(c_out, c_out, film_dim, kernel),
                                          nn.ConvTranspose1d(c_out, c_out, 4, 2, 1)]))
        self.out = nn.Sequential(ConvBlock(channels[0], channels[0], kernel), nn.Conv1d(channels[0], action_dim, 1))

    def forward(self, actions: torch.Tensor, cond: torch.Tensor, step: torch.Tensor) -> torch.Tensor:
        """Predicted noise."""
        film = torch.cat([self.step_in(step), cond], dim=-1)
        x = actions.transpose(1, 2)
        skips = []
        for block1, block2, downsample in self.down:
            x = block2(block1(x, film), film)
            skips.append(x)
            x = downsample(x)
        for block in self.mid:
            x = block(x, film)
        for block1, block2, upsample in self.up:
            x = torch.cat([x, skips.pop()], dim=1)
            x = upsample(block2(block1(x, film), film))
        return self.out(x).transpose(1, 2)
