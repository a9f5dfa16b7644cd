"""The policy: observation encoder + generative action head + normalisation, with save/load.

API used by the evaluation runner and the later ROS ``policy_node``::

    policy = Policy.load("models/sorting")
    embedding = policy.embed(obs_history)            # ndarray [E] float32, O^e
    chunks = policy.sample(embedding, 32, generator)  # ndarray [B, H, D] float32, one batched pass
"""
from __future__ import annotations

import logging
import pickle
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from torch import nn

from .config import PolicyConfig
from .diffusion import Diffusion
from .encoder import CAMERAS, ObservationEncoder, preprocess_images
from .errors import PolicyError
from .flow_matching import FlowMatching
from .normalizer import RangeNormalizer
from .transformer import ChunkTransformer
from .unet1d import TemporalUnet

LOG = logging.getLogger(__name__)
WEIGHTS_FILE = "policy.pt"
CONFIG_FILE = "policy.yaml"
Observation = Mapping[str, np.ndarray]


class Policy(nn.Module):
    """Generative chunk policy ``pi(A | O)`` with an explicit embedding ``O^e``."""

    def __init__(self, config: PolicyConfig, action_stats: RangeNormalizer, proprio_stats: RangeNormalizer) -> None:
        super().__init__()
        self.config = config
        self.encoder = ObservationEncoder(config.image_size, config.encoder_channels, config.proprio_dim,
                                          config.obs_horizon, config.embed_dim)
        self.actions = action_stats
        self.proprio = proprio_stats
        self.net: nn.Module
        self.process: FlowMatching | Diffusion
        if config.head == "flow":
            self.net = ChunkTransformer(config.action_dim, config.horizon, config.embed_dim, config.transformer_width,
                                        config.transformer_layers, config.transformer_heads)
            self.process = FlowMatching(config.integration_steps)
        elif config.head == "diffusion":
            self.net = TemporalUnet(config.action_dim, config.embed_dim, config.unet_channels)
            self.process = Diffusion(config.diffusion_train_steps, config.diffusion_sample_steps, config.diffusion_eta)
        else:
            raise ValueError(f"unknown head {config.head!r}; expected 'flow' or 'diffusion'")

    # ------------------------------------------------------------------ tensors
    def encode(self, images: Sequence[torch.Tensor], proprio: torch.Tensor) -> torch.Tensor:
        """Embeddings ``[N, E]`` of uint8 images (one ``[N, T_h, 3, S, S]`` per camera), raw proprio ``[N, T_h, P]``."""
        return self.encoder(images, self.proprio.normalize(proprio))

    def loss(self, embedding: torch.Tensor, actions: torch.Tensor, generator: torch.Generator) -> torch.Tensor:
        """Generative loss of raw action chunks ``[N, H, D]`` given embeddings ``[N, E]``."""
        return self.process.loss(self.net, self.actions.normalize(actions), embedding, generator)

    # ------------------------------------------------------------------ numpy API
    def observation_tensors(self, obs_history: Sequence[Observation]) -> tuple[list[torch.Tensor], torch.Tensor]:
        """Batch-of-one tensors of the last ``T_h`` observations (the first one repeated if fewer)."""
        if not obs_history:
            raise ValueError("empty observation history")
        frames = list(obs_history)[-self.config.obs_horizon:]
        frames = [frames[0]] * (self.config.obs_horizon - len(frames)) + frames
        images = [preprocess_images(np.stack([f[cam] for f in frames]), self.config.image_size)[None]
                  for cam in CAMERAS]
        proprio = torch.from_numpy(np.stack([np.asarray(f["proprio"], dtype=np.float32) for f in frames]))[None]
        if proprio.shape[-1] != self.config.proprio_dim:
            raise ValueError(f"expected proprio of size {self.config.proprio_dim}, got {proprio.shape[-1]}")
        return images, proprio

    @torch.no_grad()
    def embed(self, obs_history: Sequence[Observation]) -> np.ndarray:
        """Observation embedding ``O^e`` float32 ``[E]`` of the latest ``T_h`` observations."""
        self.eval()
        images, proprio = self.observation_tensors(obs_history)
        return self.encode(images, proprio)[0].numpy().astype(np.float32)

    @torch.no_grad()
    def sample(self, embedding: np.ndarray, batch: int | None = None,
               generator: torch.Generator | None = None) -> np.ndarray:
        """``B`` action chunks float32 ``[B, H, D]`` in physical units, sampled in one batched pass.

        The embedding is repeated ``B`` times and the whole batch goes through the sampler together.
        Without a ``generator`` the noise comes from torch's global generator (``torch.manual_seed``).
        """
        self.eval()
        batch = self.config.sample_batch if batch is None else int(batch)
        generator = generator if generator is not None else torch.default_generator
        cond = torch.as_tensor(np.asarray(embedding, dtype=np.float32)).reshape(1, -1).expand(batch, -1)
        noise = torch.randn((batch, self.config.horizon, self.config.action_dim), generator=generator)
        chunks = self.process.sample(self.net, cond, noise, generator)
        return self.actions.unnormalize(chunks).numpy().astype(np.float32)

    def act(self, obs_history: Sequence[Observation], batch: int | None = None,
            generator: torch.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
        """``(embedding [E], chunks [B, H, D])`` for the current observation history."""
        embedding = self.embed(obs_history)
        return embedding, self.sample(embedding, batch, generator)

    # ------------------------------------------------------------------ persistence
    def save(self, directory: str | Path, info: Mapping[str, Any] | None = None) -> Path:
        """Write ``policy.pt`` (state dict) and ``policy.yaml`` (config, stats, ``info``) to ``directory``."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        torch.save(self.state_dict(), directory / WEIGHTS_FILE)
        document = {"config": self.config.to_dict(), "action_stats": self.actions.stats(),
                    "proprio_stats": self.proprio.stats(), "info": dict(info or {})}
        (directory / CONFIG_FILE).write_text(yaml.safe_dump(document, sort_keys=False))
        LOG.info("saved policy to %s", directory)
        return directory

    @classmethod
    def load(cls, directory: str | Path) -> Policy:
        """Read a policy written by :meth:`save` (eval mode).

        Raises:
            PolicyError: ``directory`` lacks ``policy.yaml`` or ``policy.pt`` (the message names them), or they
                cannot be read as a policy of this code (the message names the folder and the reader's error).
        """
        directory = Path(directory)
        missing = [name for name in (CONFIG_FILE, WEIGHTS_FILE) if not (directory / name).is_file()]
        if missing:
            raise PolicyError(f"policy folder {directory.resolve()} lacks {' and '.join(missing)}: not a policy model "
                              "folder (train one first, docs/policies.md)")
        try:
            document = yaml.safe_load((directory / CONFIG_FILE).read_text())
            config = PolicyConfig.from_dict(document["config"])
            policy = cls(config, RangeNormalizer(**document["action_stats"]),
                         RangeNormalizer(**document["proprio_stats"]))
            weights = torch.load(directory / WEIGHTS_FILE, map_location="cpu", weights_only=True)
            policy.load_state_dict(weights)  # a RuntimeError for weights of another network
        except (OSError, EOFError, yaml.YAMLError, pickle.UnpicklingError, KeyError, TypeError, ValueError,
                RuntimeError) as error:
            raise PolicyError(f"{directory}: cannot load the policy ({type(error).__name__}: {error})") from error
        return policy.eval()
