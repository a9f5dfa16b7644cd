"""Tiny policies, random observations and synthetic demonstrations for the policy tests."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from fiper_ros.policy.config import PRESETS, PolicyConfig
from fiper_ros.policy.normalizer import RangeNormalizer
from fiper_ros.policy.policy import Policy


def tiny_config(task: str = "sorting", **changes: object) -> PolicyConfig:
    """A task preset shrunk to train in a second."""
    head = {"transformer_width": 16, "transformer_layers": 1, "transformer_heads": 2, "integration_steps": 4,
            "unet_channels": (8, 16), "diffusion_sample_steps": 4}
    small = {"image_size": 16, "encoder_channels": (4, 8), "embed_dim": 16, "batch_size": 8, "epochs": 1,
             "sample_batch": 6, **head}
    return PRESETS[task].with_overrides(**{**small, **changes})


def tiny_policy(task: str = "sorting", seed: int = 0, **changes: object) -> Policy:
    """An untrained policy of :func:`tiny_config` with random action statistics (eval mode)."""
    config = tiny_config(task, **changes)
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    low = rng.normal(size=config.action_dim)
    return Policy(config, RangeNormalizer(low, low + 1.0 + rng.random(config.action_dim)),
                  RangeNormalizer(-np.ones(config.proprio_dim), np.ones(config.proprio_dim))).eval()


def random_observation(config: PolicyConfig, seed: int = 0) -> dict[str, np.ndarray]:
    """A random observation as the sim produces it: two 96x96 rgb8 cameras and the proprio vector."""
    rng = np.random.default_rng(seed)
    return {"wrist_rgb": rng.integers(0, 255, (96, 96, 3), dtype=np.uint8),
            "third_rgb": rng.integers(0, 255, (96, 96, 3), dtype=np.uint8),
            "proprio": rng.normal(size=config.proprio_dim).astype(np.float32)}


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
