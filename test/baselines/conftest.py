"""Small rollouts for the baseline tests: 2-D embedding clusters and smooth action chunks."""

from __future__ import annotations

import numpy as np

from fiper_ros.core.rollout import Rollout

HORIZON, DIMS, EXEC = 8, 2, 4


def cluster_rollout(rng: np.random.Generator, index: int, center: tuple[float, float], steps: int = 30,
                    success: bool = True) -> Rollout:
    """Embeddings from a tight 2-D Gaussian cluster at ``center``; simple action chunks."""
    embeddings = np.asarray(center) + 0.1 * rng.normal(size=(steps, 2))
    actions = 0.01 * rng.normal(size=(steps, 8, HORIZON, DIMS))
    return Rollout(f"cluster-{index}", "test", "id", embeddings, actions, EXEC, success)


def chunk_rollout(rng: np.random.Generator, index: int, noise: float, steps: int = 20, samples: int = 16) -> Rollout:
    """Action chunks along a straight line per sample (consistent overlaps) plus ``noise``."""
    env_steps = np.arange(steps)[:, None] * EXEC + np.arange(HORIZON)[None, :]
    slope = rng.uniform(0.5, 1.0, (1, samples, 1, DIMS))
    actions = 0.01 * env_steps[:, None, :, None] * slope + noise * rng.normal(size=(steps, samples, HORIZON, DIMS))
    embeddings = rng.normal(size=(steps, 2))
    return Rollout(f"chunks-{index}", "test", "id", embeddings, actions, EXEC, True)
