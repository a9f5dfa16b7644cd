"""Demonstration dataset: reads the sim's ``episode_*.npz`` files, caches downsampled images in memory.

Sample ``i`` is a control step ``t`` of an episode: the observation frames ``t - T_h + 1 .. t``
(clamped at the episode start) and the chunk ``actions[t : t + H]`` padded with the last action
(docs/sim.md). Only successful episodes are used for training.
"""
from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .encoder import CAMERAS, preprocess_images
from .errors import PolicyError

LOG = logging.getLogger(__name__)


def episode_files(directory: str | Path) -> list[Path]:
    """The demo episodes of ``directory`` in seed order; :class:`~fiper_ros.policy.errors.PolicyError` for none."""
    files = sorted(Path(directory).glob("episode_*.npz"))
    files = [f for f in files if not f.name.endswith(".tmp.npz")]
    if not files:
        raise PolicyError(f"no episode_*.npz demonstrations in {directory}")
    return files


def files_hash(files: list[Path]) -> str:
    """SHA-256 over the names and bytes of the demo files (the model's training-data hash)."""
    digest = hashlib.sha256()
    for path in files:
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def sample_indices(length: int, obs_horizon: int, horizon: int) -> tuple[np.ndarray, np.ndarray]:
    """Per control step ``t`` of an episode of ``length`` steps: the frames of its observation history
    ``[length, T_h]`` (``t - T_h + 1 .. t``, clamped at the start) and of its action chunk ``[length, H]``
    (``t .. t + H - 1``, clamped at the end: padded with the last action)."""
    steps = np.arange(length)[:, None]
    return (np.clip(steps + np.arange(1 - obs_horizon, 1)[None], 0, length - 1),
            np.clip(steps + np.arange(horizon)[None], 0, length - 1))


@dataclass
class Batch:
    """A training batch: images (one uint8 ``[N, T_h, 3, S, S]`` per camera), proprio ``[N, T_h, P]``,
    actions ``[N, H, D]``."""

    images: list[torch.Tensor]
    proprio: torch.Tensor
    actions: torch.Tensor


class DemoDataset:
    """All (observation history, action chunk) pairs of the successful demonstrations, in memory
    (:class:`~fiper_ros.policy.errors.PolicyError` for a folder without a successful one)."""

    def __init__(self, directory: str | Path, obs_horizon: int, horizon: int, image_size: int,
                 max_episodes: int | None = None) -> None:
        files = episode_files(directory)
        if max_episodes is not None:
            files = files[:max_episodes]
        self.files = files
        images: dict[str, list[torch.Tensor]] = {cam: [] for cam in CAMERAS}
        proprio, actions, obs_index, chunk_index = [], [], [], []
        offset = 0
        skipped = 0
        for path in files:
            with np.load(path) as data:
                if not bool(data["success"]):
                    skipped += 1
                    continue
                length = len(data["actions"])
                for cam in CAMERAS:
                    images[cam].append(preprocess_images(data[cam], image_size, f"{path}: {cam}"))
                proprio.append(np.asarray(data["proprio"], dtype=np.float32))
                actions.append(np.asarray(data["actions"], dtype=np.float32))
            frames, chunk = sample_indices(length, obs_horizon, horizon)
            obs_index.append(offset + frames)
            chunk_index.append(offset + chunk)
            offset += length
        if not proprio:
            raise PolicyError(f"no successful demonstrations in {directory}")
        self.images = {cam: torch.cat(frames) for cam, frames in images.items()}
        self.proprio = torch.from_numpy(np.concatenate(proprio))
        self.actions = torch.from_numpy(np.concatenate(actions))
        self.obs_index = torch.from_numpy(np.concatenate(obs_index))
        self.chunk_index = torch.from_numpy(np.concatenate(chunk_index))
        self.episodes = len(proprio)
        LOG.info("loaded %d successful episodes (%d skipped), %d samples from %s", self.episodes, skipped,
                 len(self), directory)

    def __len__(self) -> int:
        return int(self.obs_index.shape[0])

    def hash(self) -> str:
        """Training-data hash of the files read."""
        return files_hash(self.files)

    def batch(self, indices: torch.Tensor, shift: int = 0, generator: torch.Generator | None = None) -> Batch:
        """The samples ``indices``; ``shift > 0`` applies a random image translation of up to ``shift`` pixels
        (replicate padding, one offset per sample and camera) as augmentation."""
        frames = self.obs_index[indices]
        images = []
        for cam in CAMERAS:
            stack = self.images[cam][frames]  # [N, T_h, 3, S, S]
            if shift > 0:
                stack = random_shift(stack, shift, generator)
            images.append(stack)
        return Batch(images, self.proprio[frames], self.actions[self.chunk_index[indices]])


def random_shift(images: torch.Tensor, shift: int, generator: torch.Generator | None) -> torch.Tensor:
    """Translate each sample's frames ``[N, T, C, S, S]`` by a random integer offset in ``[-shift, shift]``."""
    n, size = images.shape[0], images.shape[-1]
    padded = torch.nn.functional.pad(images.flatten(1, 2).float(), (shift,) * 4, mode="replicate").to(images.dtype)
    offsets = torch.randint(0, 2 * shift + 1, (n, 2), generator=generator).tolist()
    out = torch.stack([padded[i, :, dy:dy + size, dx:dx + size] for i, (dy, dx) in enumerate(offsets)])
    return out.reshape(images.shape)
