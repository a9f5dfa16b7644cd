"""Conditional flow matching (App. B.3.2): linear path ``A^s = (1 - s) A^0 + s A^1``, Euler sampling.

``A^1 ~ N(0, I)`` is the source and ``A^0`` the (normalised) action chunk; the network regresses the
velocity ``A^0 - A^1`` and sampling integrates ``A^{s - ds} = A^s + ds v(A^s, O^e, s)`` from ``s = 1``.
"""
from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn


class FlowMatching:
    """Loss and Euler sampler around a velocity network ``net(A^s, cond, s)``."""

    def __init__(self, steps: int) -> None:
        if steps < 1:
            raise ValueError(f"integration steps must be >= 1, got {steps}")
        self.steps = steps

    def loss(self, net: nn.Module, actions: torch.Tensor, cond: torch.Tensor,
             generator: torch.Generator) -> torch.Tensor:
        """Mean squared velocity error on a batch of normalised chunks ``[N, H, D]``."""
        noise = torch.randn(actions.shape, generator=generator)
        s = torch.rand(actions.shape[0], generator=generator)
        path = (1.0 - s[:, None, None]) * actions + s[:, None, None] * noise
        return F.mse_loss(net(path, cond, s), actions - noise)

    @torch.no_grad()
    def sample(self, net: nn.Module, cond: torch.Tensor, noise: torch.Tensor,
               generator: torch.Generator) -> torch.Tensor:
        """Integrate from ``A^1 = noise [N, H, D]`` to ``A^0`` (deterministic given the noise)."""
        del generator  # the ODE is deterministic; kept for the common head interface
        x = noise
        ds = 1.0 / self.steps
        for k in range(self.steps, 0, -1):
            s = torch.full((x.shape[0],), k * ds)
            x = x + ds * net(x, cond, s)
        return x
