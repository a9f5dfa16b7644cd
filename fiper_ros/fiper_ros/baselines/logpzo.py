"""logpZO: flow matching on observation embeddings (Xu et al., "Can We Detect Failures Without
Failure Data? Uncertainty-Aware Runtime Failure Detection for Imitation Learning Policies", RSS 2025,
the FAIL-Detect code; App. B.5 of the FIPER paper).

A velocity field ``v(x, s)`` is learned by conditional flow matching between the (standardised)
embeddings at ``s = 0`` and standard Gaussian noise ``z`` at ``s = 1``:
``x_s = (1 - s) x_0 + s z`` with target velocity ``z - x_0``. This is FAIL-Detect's time convention;
the FIPER appendix writes the same straight path with data at ``s = 0`` and noise at ``s = 1`` but
the opposite velocity sign (``u = x_0 - z``), so "solving the ODE backwards" there is integrating
``dx/ds = v`` forwards from ``s = 0`` to ``s = 1`` here. The score is the squared norm of the noise
sample reached, ``||Z||^2`` with ``Z = x + sum_k (1/n) v(x_k, k/n)`` (Euler, ``n = steps``). The
default ``n = 1`` is FAIL-Detect's ``||x + v(x, 0)||^2``.

Deviations from the original: the velocity net is a small MLP on the CPU (default
``(E+1)-256-256-E`` with ReLU, the time ``s`` appended to the input) instead of FAIL-Detect's U-Net,
and embeddings are standardised per dimension with the training mean and standard deviation (an
affine change of variables that keeps the net's inputs well scaled; ``standardize=False`` disables it).
Training: AdamW, cosine learning rate, a fixed number of epochs, seeded noise and initialisation.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Self

import numpy as np
import torch

from fiper_ros.baselines.base import BaselineError, read_model, training_rollouts, write_model
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.torch_mlp import build_mlp

LOG = logging.getLogger(__name__)

WEIGHTS_FILE = "logpzo.pt"
CONFIG_FILE = "logpzo.json"


@dataclass(frozen=True)
class LogpZOConfig:
    """Velocity net size, training budget and the number of Euler steps of the score."""

    hidden: tuple[int, ...] = (256, 256)
    epochs: int = 100
    batch_size: int = 256
    lr: float = 1e-3
    lr_min: float = 1e-5
    weight_decay: float = 1e-5
    steps: int = 1
    standardize: bool = True

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form."""
        data = asdict(self)
        data["hidden"] = list(self.hidden)
        return data


class LogpZO:
    """logpZO as a :class:`~fiper_ros.baselines.base.Baseline`."""

    name = "logpzo"

    def __init__(self, config: LogpZOConfig | None = None) -> None:
        self.config = config or LogpZOConfig()
        if self.config.steps < 1:
            raise BaselineError(f"logpZO needs at least one Euler step, got {self.config.steps}")
        self.network: torch.nn.Sequential | None = None
        self.mean = np.zeros(0)
        self.std = np.ones(0)

    def _build(self, dim: int, seed: int) -> torch.nn.Sequential:
        layers = [*((w, "relu") for w in self.config.hidden), (dim, None)]
        return build_mlp(dim + 1, layers, torch.Generator().manual_seed(seed))

    def _velocity(self, x: torch.Tensor, s: torch.Tensor) -> torch.Tensor:
        assert self.network is not None
        return self.network(torch.cat([x, s[:, None]], dim=1))

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """Flow matching on every step's embedding of the successful rollouts."""
        data = np.concatenate([r.embeddings for r in training_rollouts(rollouts)]).astype(np.float64)
        self.mean = data.mean(axis=0) if self.config.standardize else np.zeros(data.shape[1])
        self.std = np.maximum(data.std(axis=0), 1e-6) if self.config.standardize else np.ones(data.shape[1])
        x0 = torch.from_numpy(((data - self.mean) / self.std).astype(np.float32))
        self.network = self._build(x0.shape[1], seed)
        generator = torch.Generator().manual_seed(seed + 1)
        optimizer = torch.optim.AdamW(self.network.parameters(), lr=self.config.lr, weight_decay=self.config.weight_decay)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, self.config.epochs, self.config.lr_min)
        self.network.train()
        for epoch in range(self.config.epochs):
            order = torch.randperm(x0.shape[0], generator=generator)
            total = 0.0
            for start in range(0, x0.shape[0], self.config.batch_size):
                batch = x0[order[start : start + self.config.batch_size]]
                noise = torch.randn(batch.shape, generator=generator)
                s = torch.rand(batch.shape[0], generator=generator)
                xs = (1.0 - s[:, None]) * batch + s[:, None] * noise
                loss = torch.mean((self._velocity(xs, s) - (noise - batch)) ** 2)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                optimizer.step()
                total += float(loss.detach()) * batch.shape[0]
            schedule.step()
            LOG.debug("logpZO epoch %d loss %.5f", epoch + 1, total / x0.shape[0])
        self.network.eval()
        return self

    def score_embeddings(self, embeddings: np.ndarray) -> np.ndarray:
        """``||Z||^2`` ``[N]`` of embeddings ``[N, E]`` (Euler integration to ``s = 1``)."""
        if self.network is None:
            raise BaselineError("logpZO is not fitted")
        x = torch.from_numpy(((np.asarray(embeddings, dtype=np.float64) - self.mean) / self.std).astype(np.float32))
        steps = self.config.steps
        with torch.no_grad():
            for k in range(steps):
                x = x + self._velocity(x, torch.full((x.shape[0],), k / steps)) / steps
        return torch.sum(x.double() ** 2, dim=1).numpy()

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Per-step logpZO scores of ``rollout``."""
        return self.score_embeddings(rollout.embeddings)

    def save(self, directory: str | Path) -> None:
        """Write ``logpzo.pt`` (weights, standardisation) and ``logpzo.json`` (config)."""
        if self.network is None:
            raise BaselineError("logpZO is not fitted")
        state = {"network": self.network.state_dict(), "mean": torch.from_numpy(self.mean),
                 "std": torch.from_numpy(self.std)}
        write_model(directory, WEIGHTS_FILE, state, CONFIG_FILE, self.config.to_dict())

    @classmethod
    def load(cls, directory: str | Path) -> LogpZO:
        """Read a model written by :meth:`save`."""
        state, data = read_model(directory, WEIGHTS_FILE, CONFIG_FILE, "logpZO")
        model = cls(LogpZOConfig(**{**data, "hidden": tuple(data["hidden"])}))
        model.mean, model.std = state["mean"].numpy(), state["std"].numpy()
        model.network = model._build(model.mean.shape[0], 0)
        model.network.load_state_dict(state["network"])
        model.network.eval()
        return model
