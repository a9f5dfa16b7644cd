"""Synthetic rollouts of the FIPER core tests: ID rollouts and OOD ones with shifted embeddings and
widely spread action samples."""

from __future__ import annotations

import numpy as np
from fiper_ros.core.mlp import parameter_shapes
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


def cluster_rollout(rng: np.random.Generator, index: int, center: tuple[float, float], steps: int = 30,
                    success: bool = True) -> Rollout:
    """Embeddings from a tight 2-D Gaussian cluster at ``center`` (standard deviation 0.1); small random action
    chunks ``[T, 8, 8, 2]``, ``h = 4``."""
    embeddings = np.asarray(center) + 0.1 * rng.normal(size=(steps, 2))
    actions = 0.01 * rng.normal(size=(steps, 8, 8, 2))
    return Rollout(f"cluster-{index}", "test", "id", embeddings, actions, 4, success)


def filled_rnd(embedding_dim: int, config: RNDConfig, target: float, predictor: float) -> RNDOE:
    """A real RND-OE model of ``config`` whose every target weight is ``target``, every predictor weight
    ``predictor``, every bias 0."""
    def filled(layers: list, value: float) -> dict[str, np.ndarray]:
        return {name: np.full(shape, value if name.endswith("weight") else 0.0, np.float32)
                for name, shape in parameter_shapes(embedding_dim, layers).items()}

    return RNDOE(embedding_dim, config, 0, filled(config.target_layers(), target),
                 filled(config.predictor_layers(), predictor))


def overflowing_rnd(embedding_dim: int = EMBEDDING_DIM, layers: int = 8) -> RNDOE:
    """A real RND-OE model whose every weight is 3e38: its score overflows even in float64 (inf - inf)."""
    return filled_rnd(embedding_dim, RNDConfig(trunk=(1,) * layers, head=(), out_dim=1), 3e38, 3e38)
