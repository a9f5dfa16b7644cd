"""logpZO: flow matching on observation embeddings (Xu et al., "Can We Detect Failures Without Failure Data?
Uncertainty-Aware Runtime Failure Detection for Imitation Learning Policies", RSS 2025, the FAIL-Detect code;
App. B.5 of the FIPER paper).

A velocity field ``v(x, s)`` is learned by conditional flow matching between the (standardised) embeddings at
``s = 0`` and standard Gaussian noise ``z`` at ``s = 1``: ``x_s = (1 - s) x_0 + s z`` with target velocity
``z - x_0``. This is FAIL-Detect's time convention; the FIPER appendix writes the same straight path with data at
``s = 0`` and noise at ``s = 1`` but the opposite velocity sign (``u = x_0 - z``), so "solving the ODE backwards"
there is integrating ``dx/ds = v`` forwards from ``s = 0`` to ``s = 1`` here. The score of an embedding is the
squared norm of the noise sample reached, ``||Z||^2`` with ``Z = x + sum_k (1/n) v(x_k, k/n)`` (Euler,
``n = steps``); the default ``n = 1`` is FAIL-Detect's ``||x + v(x, 0)||^2``.

Deviations from the original: the velocity net is a small MLP on the CPU (default ``(E+1)-256-256-E`` with ReLU,
the time ``s`` appended to the input) instead of FAIL-Detect's U-Net, and embeddings are standardised per
dimension with the training mean and standard deviation (an affine change of variables that keeps the net's
inputs well scaled; ``standardize=False`` disables it). Training: AdamW, cosine learning rate, a fixed number of
epochs, seeded noise and initialisation.

This module is the model as it scores, in numpy and without torch (the scoring nodes import it): the velocity
net's float32 parameters (:class:`fiper_ros.core.mlp.NumpyMLP`), the standardisation, the score step by step
(:meth:`LogpZO.score_one`; a whole rollout is scored with the same function, so both agree bit for bit) and the
files ``logpzo.json`` + ``logpzo.npz`` (:mod:`fiper_ros.core.detector_model`). The training is torch's, in
:mod:`fiper_ros.core.logpzo_train`, imported by :meth:`LogpZO.fit` only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Self

import numpy as np

from fiper_ros.core.detector_model import EmbeddingDetector, check_input
from fiper_ros.core.errors import CoreError
from fiper_ros.core.mlp import LayerSpec, MLPError, NumpyMLP
from fiper_ros.core.rollout import Rollout, successful

#: Floor of the standardisation's per-dimension standard deviation (a constant dimension divides by it).
STD_FLOOR = 1e-6


class LogpZOError(CoreError):
    """Bad logpZO input (shape, NaN/inf), configuration, model files, or no successes to fit on."""


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

    def __post_init__(self) -> None:
        if self.steps < 1:
            raise LogpZOError(f"logpZO needs at least one Euler step, got {self.steps}")

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form."""
        data = asdict(self)
        data["hidden"] = list(self.hidden)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> LogpZOConfig:
        """Inverse of :meth:`to_dict`."""
        return cls(**{**data, "hidden": tuple(data["hidden"])})

    def velocity_layers(self, embedding_dim: int) -> list[LayerSpec]:
        """The velocity net ``(E+1) -> hidden (ReLU) -> E`` (the input: the embedding and the time ``s``)."""
        return [*((width, "relu") for width in self.hidden), (embedding_dim, None)]


class LogpZO(EmbeddingDetector):
    """logpZO as a :class:`~fiper_ros.baselines.base.Baseline` and a core detector: :meth:`fit` (torch, on the
    successes), :meth:`score_one` / :meth:`scores` (numpy), :meth:`save` / :meth:`load` (numpy)."""

    name: ClassVar[str] = "logpzo"
    format_version: ClassVar[int] = 1
    error: ClassVar[type[ValueError]] = LogpZOError

    def __init__(self, config: LogpZOConfig | None = None) -> None:
        self.config = config or LogpZOConfig()
        self.seed = 0
        self.network: NumpyMLP | None = None
        self.mean = np.zeros(0)
        self.std = np.ones(0)

    @property
    def embedding_dim(self) -> int:
        """``E``, the embedding size the model was fitted on (0 before fitting)."""
        return int(self.mean.shape[0])

    def standardisation(self, embeddings: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per-dimension mean and standard deviation (floored at :data:`STD_FLOOR`) of the training embeddings
        ``[N, E]`` (float64), or ``(0, 1)`` with ``standardize=False``."""
        if not self.config.standardize:
            return np.zeros(embeddings.shape[1]), np.ones(embeddings.shape[1])
        return embeddings.mean(axis=0), np.maximum(embeddings.std(axis=0), STD_FLOOR)

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """Flow matching on every step's embedding of the rollouts with ``success is True`` (others ignored; at
        least one); torch trains (:func:`fiper_ros.core.logpzo_train.train_velocity`), deterministic for a seed
        on a given machine."""
        from fiper_ros.core.logpzo_train import train_velocity  # noqa: PLC0415 - torch only where a model is trained

        good = successful(list(rollouts))
        if not good:
            raise LogpZOError("logpZO is fitted on successful rollouts: none given")
        data = np.concatenate([r.embeddings for r in good]).astype(np.float64)
        mean, std = self.standardisation(data)
        config = self.config
        parameters = train_velocity(((data - mean) / std).astype(np.float32), config.velocity_layers(data.shape[1]),
                                    epochs=config.epochs, batch_size=config.batch_size, lr=config.lr,
                                    lr_min=config.lr_min, weight_decay=config.weight_decay, seed=seed)
        self._set(seed, mean, std, parameters)
        return self

    def _set(self, seed: int, mean: np.ndarray, std: np.ndarray, parameters: dict[str, np.ndarray]) -> None:
        mean, std = np.asarray(mean, dtype=np.float64), np.asarray(std, dtype=np.float64)
        if mean.ndim != 1 or std.shape != mean.shape or not (np.isfinite(mean).all() and np.isfinite(std).all()
                                                             and (std > 0).all()):
            raise LogpZOError(f"standardisation must be finite mean and positive std of one shape, got "
                              f"{mean.shape} and {std.shape}")
        try:
            network = NumpyMLP(mean.shape[0] + 1, self.config.velocity_layers(mean.shape[0]), parameters)
        except MLPError as error:
            raise LogpZOError(f"velocity net: {error}") from error
        self.seed, self.mean, self.std, self.network = int(seed), mean, std, network

    def _input(self, embeddings: np.ndarray, shape: tuple[int | str, ...]) -> np.ndarray:
        """Checked embeddings of ``shape``, standardised, in float32 (the net's input)."""
        if self.network is None:
            raise LogpZOError("logpZO is not fitted")
        x = check_input(embeddings, shape, "embeddings", LogpZOError)
        with np.errstate(over="ignore"):  # beyond float32: inf, refused by the score's check
            return ((x.astype(np.float64) - self.mean) / self.std).astype(np.float32)

    def _score(self, x: np.ndarray) -> float:
        """``||Z||^2`` of one standardised float32 embedding ``x [E]``: the Euler steps of ``v`` in float32, the
        squared norm in float64; the one scoring function of both forms."""
        assert self.network is not None
        steps = self.config.steps
        with np.errstate(over="ignore", invalid="ignore"):
            for k in range(steps):
                velocity = self.network(np.append(x, np.float32(k / steps)))
                x = x + velocity / np.float32(steps)
            score = float(np.sum(np.square(x.astype(np.float64))))
        if not np.isfinite(score):
            raise LogpZOError("the score overflows: the embedding is beyond float32 range after standardisation")
        return score

    def describe(self) -> dict[str, Any]:
        """Configuration, seed and embedding size (the JSON description of the model)."""
        return {"config": self.config.to_dict(), "seed": self.seed, "embedding_dim": self.embedding_dim}

    def arrays(self) -> dict[str, np.ndarray]:
        """Standardisation ``mean``, ``std`` ``[E]`` and the velocity net's parameters ``velocity/<name>``."""
        if self.network is None:
            raise LogpZOError("logpZO is not fitted")
        parameters = {f"velocity/{name}": array for name, array in self.network.parameters.items()}
        return {"mean": self.mean, "std": self.std, **parameters}

    @classmethod
    def from_stored(cls, description: dict[str, Any], arrays: dict[str, np.ndarray]) -> LogpZO:
        """The model of a :meth:`describe` output and its :meth:`arrays` (:meth:`load` reads them)."""
        model = cls(LogpZOConfig.from_dict(description["config"]))
        parameters = {name.split("/", 1)[1]: array for name, array in arrays.items() if name.startswith("velocity/")}
        model._set(description["seed"], arrays["mean"], arrays["std"], parameters)
        if model.embedding_dim != description["embedding_dim"]:
            raise LogpZOError(f"embedding_dim {description['embedding_dim']}, but arrays of {model.embedding_dim}")
        return model
