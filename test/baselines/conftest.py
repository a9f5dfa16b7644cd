"""Small rollouts for the baseline tests: smooth action chunks (embedding clusters: helpers.core_data)."""

from __future__ import annotations

import numpy as np

from fiper_ros.core.rollout import Rollout

HORIZON, DIMS, EXEC = 8, 2, 4


def chunk_rollout(rng: np.random.Generator, index: int, noise: float, steps: int = 20, samples: int = 16) -> Rollout:
    """Action chunks along a straight line per sample (consistent overlaps) plus ``noise``."""
    env_steps = np.arange(steps)[:, None] * EXEC + np.arange(HORIZON)[None, :]
    slope = rng.uniform(0.5, 1.0, (1, samples, 1, DIMS))
    actions = 0.01 * env_steps[:, None, :, None] * slope + noise * rng.normal(size=(steps, samples, HORIZON, DIMS))
    embeddings = rng.normal(size=(steps, 2))
    return Rollout(f"chunks-{index}", "test", "id", embeddings, actions, EXEC, True)
