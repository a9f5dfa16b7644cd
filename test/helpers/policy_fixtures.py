"""Tiny policy configs and synthetic demonstrations for the policy tests (test/policy)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fiper_ros.policy.config import PRESETS, PolicyConfig


def tiny_config(task: str = "sorting", **changes: object) -> PolicyConfig:
    """A task preset shrunk to train in a second."""
    head = {"transformer_width": 16, "transformer_layers": 1, "transformer_heads": 2, "integration_steps": 4,
            "unet_channels": (8, 16), "diffusion_sample_steps": 4}
    small = {"image_size": 16, "encoder_channels": (4, 8), "embed_dim": 16, "batch_size": 8, "epochs": 1,
             "sample_batch": 6, **head}
    return PRESETS[task].with_overrides(**{**small, **changes})


def write_demos(directory: Path, config: PolicyConfig, episodes: int = 3, length: int = 12) -> Path:
    """Synthetic episodes in the sim's demo format (random images, smooth actions)."""
    rng = np.random.default_rng(0)
    directory.mkdir(parents=True, exist_ok=True)
    for seed in range(episodes):
        t = np.linspace(0.0, 1.0, length, dtype=np.float32)[:, None]
        actions = (rng.normal(size=(1, config.action_dim)) + t * rng.normal(size=(1, config.action_dim)))
        np.savez_compressed(
            directory / f"episode_{seed:06d}.npz",
            wrist_rgb=rng.integers(0, 255, (length, 96, 96, 3), dtype=np.uint8),
            third_rgb=rng.integers(0, 255, (length, 96, 96, 3), dtype=np.uint8),
            proprio=rng.normal(size=(length, config.proprio_dim)).astype(np.float32),
            actions=actions.astype(np.float32), success=True, failed=False, seed=seed, task=config.task,
            scenario="id", control_hz=10.0, horizon=config.horizon, exec_steps=config.exec_steps)
    return directory
