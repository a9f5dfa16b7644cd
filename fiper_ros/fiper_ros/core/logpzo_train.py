"""Training logpZO's velocity net with torch (conditional flow matching, :mod:`fiper_ros.core.logpzo`).

Per batch of standardised embeddings ``x_0``: noise ``z ~ N(0, I)`` and times ``s ~ U(0, 1)`` from one seeded
generator, ``x_s = (1 - s) x_0 + s z``, loss the mean squared error of ``v(x_s, s)`` against ``z - x_0``. AdamW
(``lr``, ``weight_decay``), cosine schedule to ``lr_min`` over a fixed number of epochs, the batch
loop of :func:`fiper_ros.core.torch_mlp.train_epoch`; the net built by :func:`fiper_ros.core.torch_mlp.build_mlp`
(orthogonal initialisation, seeded). Deterministic for a seed on a given machine. Only
:meth:`fiper_ros.core.logpzo.LogpZO.fit` imports this module (lazily): scoring needs numpy alone.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np
import torch

from fiper_ros.core.mlp import LayerSpec
from fiper_ros.core.torch_mlp import build_mlp, deterministic, parameters_of, train_epoch

LOG = logging.getLogger(__name__)


def train_velocity(x0: np.ndarray, layers: Sequence[LayerSpec], *, epochs: int, batch_size: int, lr: float,
                   lr_min: float, weight_decay: float, seed: int) -> dict[str, np.ndarray]:
    """The float32 parameters (torch's names) of the velocity net ``(E+1) -> layers`` trained on the standardised
    embeddings ``x0 [N, E]`` (float32) for ``epochs`` epochs of batches of ``batch_size``."""
    x = torch.from_numpy(np.ascontiguousarray(x0, dtype=np.float32))
    network = build_mlp(x.shape[1] + 1, layers, torch.Generator().manual_seed(seed))
    generator = torch.Generator().manual_seed(seed + 1)
    optimizer = torch.optim.AdamW(network.parameters(), lr=lr, weight_decay=weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, epochs, lr_min)

    def loss_of(index: torch.Tensor) -> torch.Tensor:
        batch = x[index]
        noise = torch.randn(batch.shape, generator=generator)
        s = torch.rand(batch.shape[0], generator=generator)
        xs = (1.0 - s[:, None]) * batch + s[:, None] * noise
        return torch.mean((network(torch.cat([xs, s[:, None]], dim=1)) - (noise - batch)) ** 2)

    network.train()
    with deterministic():
        for epoch in range(epochs):
            loss = train_epoch(optimizer, torch.randperm(x.shape[0], generator=generator), batch_size, loss_of)
            schedule.step()
            LOG.debug("logpZO epoch %d loss %.5f", epoch + 1, loss)
    network.eval()
    return parameters_of(network)
