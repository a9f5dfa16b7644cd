"""RND-A: random network distillation on action chunks (adapted from He et al., "ReDiffuser:
Reliable Decision-Making Using a Diffuser with Confidence Estimation", ICML 2024; App. B.5 of the
FIPER paper).

Target ``g`` and predictor ``f`` read one action chunk ``[H, D]``: a 1-D convolution over the horizon
(``D`` input channels, ``channels`` output channels, kernel ``kernel``, LeakyReLU), flattened, then
the MLPs of RND-OE (:func:`fiper_ros.core.torch_mlp.build_mlp`: target trunk + output, predictor trunk +
head + output; orthogonal init, gain ``sqrt(2)``). Chunks are standardised per channel with the
training mean and standard deviation (a fixed layer of both networks). Training is RND-OE's loop
(:meth:`fiper_ros.core.rnd_train.TorchRND.train`: mean ``||f - g||_2``, AdamW, cosine schedule, early
stopping), which this class inherits.

Score of a policy step: the mean of ``||f(A) - g(A)||_2`` over the first ``score_samples`` of its
``B`` sampled chunks (samples of a batch are i.i.d., so the first ones are an unbiased subset).
Training uses the first ``train_samples`` chunks of every step of the successful calibration
rollouts. Both subsets bound the CPU cost for large ``B`` (PushT: 256); set them to ``B`` for all.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
import torch
from torch import nn

from fiper_ros.baselines.base import BaselineError, read_model, training_rollouts, write_model
from fiper_ros.core.mlp import LayerSpec
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rnd_train import TorchRND
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.torch_mlp import build_mlp

WEIGHTS_FILE = "rnd_a.pt"
CONFIG_FILE = "rnd_a.json"

#: CPU default of the MLP part: target ``C*H-128-128-32``, predictor ``...-128-32``; shorter training.
DEFAULT_RND = RNDConfig(trunk=(128, 128), head=(128,), out_dim=32, max_epochs=60, lr=1e-3)


@dataclass(frozen=True)
class RNDAConfig:
    """Convolution size, sample subsets and the RND network/training configuration."""

    channels: int = 32
    kernel: int = 3
    train_samples: int = 4
    score_samples: int = 32
    rnd: RNDConfig = DEFAULT_RND

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form."""
        data = asdict(self)
        data["rnd"] = self.rnd.to_dict()
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RNDAConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(**{**data, "rnd": RNDConfig.from_dict(data["rnd"])})


class ChunkNetwork(nn.Module):
    """Standardise ``[N, H*D]`` flattened chunks, convolve over ``H`` (channels ``D``), then an MLP."""

    def __init__(self, horizon: int, dims: int, config: RNDAConfig, layers: list[LayerSpec],
                 generator: torch.Generator) -> None:
        super().__init__()
        self.horizon, self.dims = horizon, dims
        self.register_buffer("mean", torch.zeros(dims))
        self.register_buffer("std", torch.ones(dims))
        self.conv = nn.Conv1d(dims, config.channels, config.kernel, padding=config.kernel // 2)
        with torch.no_grad():
            nn.init.orthogonal_(self.conv.weight, gain=math.sqrt(2.0), generator=generator)
            nn.init.zeros_(self.conv.bias)
        self.activation = nn.LeakyReLU()
        length = horizon + 2 * (config.kernel // 2) - config.kernel + 1
        self.mlp = build_mlp(config.channels * length, layers, generator)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """``[N, H*D]`` -> ``[N, m]``."""
        chunks = (x.view(-1, self.horizon, self.dims) - self.mean) / self.std
        return self.mlp(self.activation(self.conv(chunks.transpose(1, 2))).flatten(1))


class ChunkRND(TorchRND):
    """RND over flattened chunks ``[N, H*D]``: RND-OE's training loop and torch scoring, chunk networks."""

    def __init__(self, horizon: int, dims: int, config: RNDAConfig, seed: int = 0) -> None:
        self.horizon, self.dims, self.chunk_config = int(horizon), int(dims), config
        super().__init__(self.horizon * self.dims, config.rnd, seed)
        generator = torch.Generator().manual_seed(self.seed)
        self.target = ChunkNetwork(self.horizon, self.dims, config, config.rnd.target_layers(), generator)
        self.target.requires_grad_(False).eval()
        self.predictor = ChunkNetwork(self.horizon, self.dims, config, config.rnd.predictor_layers(), generator)
        self.predictor.eval()

    def standardize_with(self, chunks: np.ndarray) -> None:
        """Set both networks' per-channel standardisation from training chunks ``[N, H*D]``."""
        flat = chunks.reshape(-1, self.dims)
        mean = torch.from_numpy(flat.mean(axis=0).astype(np.float32))
        std = torch.from_numpy(np.maximum(flat.std(axis=0), 1e-6).astype(np.float32))
        for network in (self.target, self.predictor):
            network.mean.copy_(mean)
            network.std.copy_(std)


class RNDA:
    """RND-A as a :class:`~fiper_ros.baselines.base.Baseline`."""

    name = "rnd_a"

    def __init__(self, config: RNDAConfig | None = None) -> None:
        self.config = config or RNDAConfig()
        self.model: ChunkRND | None = None

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """Train on the first ``train_samples`` chunks of every step of the successful rollouts."""
        good = training_rollouts(rollouts, minimum=2)
        _, _, horizon, dims = good[0].actions.shape
        self.model = ChunkRND(horizon, dims, self.config, seed)
        k = self.config.train_samples
        chunks = np.concatenate([r.actions[:, :k].reshape(-1, horizon * dims) for r in good])
        self.model.standardize_with(chunks)
        self.model.train(chunks)
        return self

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Per-step mean RND distance over the first ``score_samples`` chunks."""
        if self.model is None:
            raise BaselineError("RND-A is not fitted")
        steps, samples, horizon, dims = rollout.actions.shape
        if (horizon, dims) != (self.model.horizon, self.model.dims):
            raise BaselineError(f"RND-A expects chunks [{self.model.horizon}, {self.model.dims}], got [{horizon}, {dims}]")
        k = min(self.config.score_samples, samples)
        distances = self.model.score(rollout.actions[:, :k].reshape(-1, horizon * dims))
        return distances.reshape(steps, k).mean(axis=1)

    def save(self, directory: str | Path) -> None:
        """Write ``rnd_a.pt`` (both networks) and ``rnd_a.json`` (shape, config, seed)."""
        if self.model is None:
            raise BaselineError("RND-A is not fitted")
        state = {"target": self.model.target.state_dict(), "predictor": self.model.predictor.state_dict()}
        meta = {"horizon": self.model.horizon, "dims": self.model.dims, "seed": self.model.seed,
                "config": self.config.to_dict()}
        write_model(directory, WEIGHTS_FILE, state, CONFIG_FILE, meta)

    @classmethod
    def load(cls, directory: str | Path) -> RNDA:
        """Read a model written by :meth:`save`."""
        state, meta = read_model(directory, WEIGHTS_FILE, CONFIG_FILE, "RND-A")
        baseline = cls(RNDAConfig.from_dict(meta["config"]))
        baseline.model = ChunkRND(meta["horizon"], meta["dims"], baseline.config, meta["seed"])
        baseline.model.target.load_state_dict(state["target"])
        baseline.model.predictor.load_state_dict(state["predictor"])
        return baseline
