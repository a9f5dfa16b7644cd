"""DDPM (App. B.3.1): cosine noise schedule, epsilon prediction; DDIM sampling with fewer steps.

Training uses ``R`` diffusion steps; sampling runs a strided DDIM (``eta`` = 0 is deterministic given
the initial noise, ``eta`` = 1 re-injects DDPM-like noise) over ``sample_steps`` of them, because the
full 100-step DDPM chain is too slow for ``B = 256`` chunks on a 2-core CPU.
"""
from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import nn


def cosine_alpha_bar(steps: int, s: float = 0.008, max_beta: float = 0.999) -> torch.Tensor:
    """Cumulative products ``alpha_bar_r`` (r = 1..R) of the cosine schedule (Nichol & Dhariwal 2021)."""
    def f(t: float) -> float:
        return math.cos((t / steps + s) / (1 + s) * math.pi / 2) ** 2

    betas = torch.tensor([min(1 - f(r + 1) / f(r), max_beta) for r in range(steps)], dtype=torch.float64)
    return torch.cumprod(1.0 - betas, dim=0).float()


class Diffusion:
    """Loss and DDIM sampler around a noise network ``net(A^r, cond, r)`` (``r`` in 0..R-1)."""

    def __init__(self, train_steps: int, sample_steps: int, eta: float = 0.0) -> None:
        if not 1 <= sample_steps <= train_steps:
            raise ValueError(f"need 1 <= sample_steps <= train_steps, got {sample_steps}, {train_steps}")
        self.train_steps = train_steps
        self.sample_steps = sample_steps
        self.eta = eta
        self.alpha_bar = cosine_alpha_bar(train_steps)

    def loss(self, net: nn.Module, actions: torch.Tensor, cond: torch.Tensor,
             generator: torch.Generator) -> torch.Tensor:
        """Mean squared noise-prediction error on a batch of normalised chunks ``[N, H, D]``."""
        noise = torch.randn(actions.shape, generator=generator)
        r = torch.randint(0, self.train_steps, (actions.shape[0],), generator=generator)
        a_bar = self.alpha_bar[r][:, None, None]
        noisy = a_bar.sqrt() * actions + (1.0 - a_bar).sqrt() * noise
        return F.mse_loss(net(noisy, cond, r), noise)

    @torch.no_grad()
    def sample(self, net: nn.Module, cond: torch.Tensor, noise: torch.Tensor,
               generator: torch.Generator) -> torch.Tensor:
        """Denoise ``A^R = noise [N, H, D]`` to ``A^0`` with a strided DDIM chain, clipped to [-1, 1]."""
        steps = torch.linspace(self.train_steps - 1, 0, self.sample_steps).round().long().tolist()
        x = noise
        for index, r in enumerate(steps):
            a_bar = self.alpha_bar[r]
            a_prev = self.alpha_bar[steps[index + 1]] if index + 1 < len(steps) else torch.tensor(1.0)
            eps = net(x, cond, torch.full((x.shape[0],), r))
            x0 = ((x - (1 - a_bar).sqrt() * eps) / a_bar.sqrt()).clamp(-1.0, 1.0)
            eps = (x - a_bar.sqrt() * x0) / (1 - a_bar).sqrt()
            sigma = self.eta * ((1 - a_prev) / (1 - a_bar) * (1 - a_bar / a_prev)).clamp(min=0).sqrt()
            x = a_prev.sqrt() * x0 + (1 - a_prev - sigma**2).clamp(min=0).sqrt() * eps
            if self.eta > 0 and index + 1 < len(steps):
                x = x + sigma * torch.randn(x.shape, generator=generator)
        return x
