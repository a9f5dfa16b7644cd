"""Synthetic rollouts of the FIPER core tests: ID rollouts and OOD ones with shifted embeddings and
widely spread action samples."""

from __future__ import annotations

import numpy as np
from fiper_ros.core.rnd_oe import RNDOE, RNDConfig
from fiper_ros.core.rollout import Rollout

EMBEDDING_DIM = 12
SAMPLES, HORIZON, ACTION_DIM = 24, 8, 4  # 3 EE position channels + gripper

TINY_RND = RNDConfig(trunk=(64, 64), head=(64,), out_dim=16, max_epochs=25, lr=1e-3)


def make_rollout(
    rng: np.random.Generator, index: int, *, ood: bool = False, success: bool = True, length: int | None = None
) -> Rollout:
    """A rollout whose OOD variant has shifted embeddings and widely spread action samples."""
    steps = int(rng.integers(18, 26)) if length is None else length
    center = np.linspace(-1.0, 1.0, EMBEDDING_DIM)
    embeddings = center + 0.2 * rng.normal(size=(steps, EMBEDDING_DIM)) + (1.5 if ood else 0.0)
    path = np.cumsum(0.1 * rng.normal(size=(steps, 1, HORIZON, ACTION_DIM)), axis=2)
    actions = path + (0.6 if ood else 0.03) * rng.normal(size=(steps, SAMPLES, HORIZON, ACTION_DIM))
    return Rollout(
        rollout_id=f"{'ood' if ood else 'id'}-{index}",
        task="synthetic",
        scenario="shift" if ood else "id",
        embeddings=embeddings,
        actions=actions,
        exec_steps=4,
        success=success,
    )


def overflowing_rnd(embedding_dim: int = EMBEDDING_DIM, layers: int = 8) -> RNDOE:
    """A real RND-OE model whose every weight is 3e38: its score overflows even in float64 (inf - inf)."""
    import torch

    model = RNDOE(embedding_dim, RNDConfig(trunk=(1,) * layers, head=(), out_dim=1), seed=0)
    with torch.no_grad():
        for network in (model.target, model.predictor):
            for parameter in network.parameters():
                parameter.fill_(3e38)
    model._cache_numpy()
    return model
