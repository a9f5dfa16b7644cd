"""Random network distillation on observation embeddings (RND-OE), eq. (1) and App. A.2.

A frozen, randomly initialised target network ``g`` and a trained predictor ``f_theta`` map an
observation embedding ``O_t^e`` to ``R^m``; the RND-OE score is ``s_RND(O_t) = ||f(O_t) - g(O_t)||_2``
(eq. 1) and training minimises its mean over the ID calibration steps.

Architecture (App. A.2): target ``E-1024-2048-4096-m`` with LeakyReLU after every layer but the
last; predictor the same trunk, then ``2048-1024`` with ReLU, then ``m``. :meth:`RNDConfig.paper`
is that model (``m = 512`` as in the authors' code); :meth:`RNDConfig.small` is the CPU default.
Training (App. A.2, training-parameter table): AdamW (lr 1e-4, weight decay 1e-5, eps 1e-8),
cosine schedule to 1e-6, batch 256, at most 250 epochs, early stopping with patience 7 on a
0.9/0.1 train/validation split.
"""

from __future__ import annotations

import json
import logging
import pickle
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fiper_ros.core.mlp import LayerSpec, NumpyMLP, build_mlp, state_digest

LOG = logging.getLogger(__name__)

WEIGHTS_FILE = "rnd_oe.pt"
CONFIG_FILE = "rnd_oe.json"


class RNDError(ValueError):
    """Bad RND-OE input, configuration or model files."""


@dataclass(frozen=True)
class RNDConfig:
    """Network sizes and training parameters of an RND model.

    Attributes:
        trunk: Hidden widths shared by target and predictor (LeakyReLU).
        head: Extra predictor widths after the trunk (ReLU).
        out_dim: Output dimension ``m``.
    """

    trunk: tuple[int, ...] = (256, 256)
    head: tuple[int, ...] = (256,)
    out_dim: int = 64
    batch_size: int = 256
    max_epochs: int = 250
    lr: float = 1e-4
    lr_min: float = 1e-6
    weight_decay: float = 1e-5
    eps: float = 1e-8
    patience: int = 7
    val_fraction: float = 0.1

    def __post_init__(self) -> None:
        if self.max_epochs < 1:
            raise RNDError(f"RND-OE needs at least one training epoch, got max_epochs {self.max_epochs}")

    @classmethod
    def paper(cls) -> RNDConfig:
        """The paper's model: ``E-1024-2048-4096-m`` target, ``...-2048-1024-m`` predictor, ``m = 512``."""
        return cls(trunk=(1024, 2048, 4096), head=(2048, 1024), out_dim=512)

    @classmethod
    def small(cls) -> RNDConfig:
        """CPU default: ``E-256-256-64`` target, ``E-256-256-256-64`` predictor."""
        return cls()

    def target_layers(self) -> list[LayerSpec]:
        """Layer specification of ``g``."""
        return [*((w, "leaky_relu") for w in self.trunk), (self.out_dim, None)]

    def predictor_layers(self) -> list[LayerSpec]:
        """Layer specification of ``f_theta``."""
        return [*((w, "leaky_relu") for w in self.trunk), *((w, "relu") for w in self.head), (self.out_dim, None)]

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (lists instead of tuples) for YAML/JSON."""
        data = asdict(self)
        data["trunk"] = list(self.trunk)
        data["head"] = list(self.head)
        return data

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RNDConfig:
        """Inverse of :meth:`to_dict`."""
        data = dict(data)
        data["trunk"] = tuple(data["trunk"])
        data["head"] = tuple(data["head"])
        return cls(**data)


@dataclass(frozen=True)
class TrainProgress:
    """Reported after every training epoch."""

    epoch: int
    max_epochs: int
    train_loss: float
    val_loss: float
    best_val_loss: float


ProgressCallback = Callable[[TrainProgress], None]


@contextmanager
def _deterministic() -> Iterator[None]:
    previous = torch.are_deterministic_algorithms_enabled()
    torch.use_deterministic_algorithms(True, warn_only=True)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(previous)


def _adamw(params: Any, config: RNDConfig) -> torch.optim.AdamW:
    kwargs = {"lr": config.lr, "weight_decay": config.weight_decay, "eps": config.eps}
    try:
        return torch.optim.AdamW(params, fused=True, **kwargs)
    except (RuntimeError, TypeError):
        return torch.optim.AdamW(params, **kwargs)


def _mean_distance(predictor: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Training loss (eq. 1): the mean over samples of ``||f(x) - g(x)||_2``, ``y = g(x)``."""
    return torch.linalg.vector_norm(predictor(x) - y, dim=1).mean()


class RNDOE:
    """An RND-OE model; construct untrained with ``RNDOE(E, config, seed)`` or use :meth:`fit`."""

    def __init__(self, embedding_dim: int, config: RNDConfig | None = None, seed: int = 0) -> None:
        if embedding_dim < 1:
            raise RNDError(f"embedding_dim must be >= 1, got {embedding_dim}")
        self.embedding_dim = int(embedding_dim)
        self.config = config or RNDConfig.small()
        self.seed = int(seed)
        generator = torch.Generator().manual_seed(self.seed)
        self.target = build_mlp(self.embedding_dim, self.config.target_layers(), generator).requires_grad_(False)
        self.predictor = build_mlp(self.embedding_dim, self.config.predictor_layers(), generator)
        self.target.eval()
        self.predictor.eval()
        self._cache_numpy()

    def _cache_numpy(self) -> None:
        self._np_target = NumpyMLP(self.target)
        self._np_predictor = NumpyMLP(self.predictor)

    def _check_batch(self, x: np.ndarray) -> np.ndarray:
        x = np.asarray(x, dtype=np.float32)
        if x.ndim != 2 or x.shape[1] != self.embedding_dim:
            raise RNDError(f"expected embeddings [N, {self.embedding_dim}], got shape {x.shape}")
        if not np.all(np.isfinite(x)):
            raise RNDError("embeddings contain NaN/inf")
        return x

    @classmethod
    def fit(
        cls,
        embeddings: np.ndarray,
        config: RNDConfig | None = None,
        seed: int = 0,
        progress: ProgressCallback | None = None,
    ) -> RNDOE:
        """Train a predictor on ID embeddings ``[N, E]`` (every policy step is one sample)."""
        model = cls(np.asarray(embeddings).shape[-1], config, seed)
        model.train(embeddings, progress)
        return model

    def train(self, embeddings: np.ndarray, progress: ProgressCallback | None = None) -> None:
        """Train the predictor in place; deterministic for a fixed seed on a fixed machine."""
        x = torch.from_numpy(self._check_batch(embeddings))
        if x.shape[0] < 2:
            raise RNDError(f"RND-OE training needs at least 2 samples, got {x.shape[0]}")
        config = self.config
        generator = torch.Generator().manual_seed(self.seed + 1)
        with _deterministic(), torch.no_grad():
            y = self.target(x)
        order = torch.randperm(x.shape[0], generator=generator)
        n_val = min(max(1, round(config.val_fraction * x.shape[0])), x.shape[0] - 1)
        val_idx, train_idx = order[:n_val], order[n_val:]
        optimizer = _adamw(self.predictor.parameters(), config)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.max_epochs, eta_min=config.lr_min)
        best_loss, best_state, stale = float("inf"), None, 0
        with _deterministic():
            for epoch in range(config.max_epochs):
                self.predictor.train()
                shuffled = train_idx[torch.randperm(train_idx.shape[0], generator=generator)]
                total = 0.0
                for start in range(0, shuffled.shape[0], config.batch_size):
                    batch = shuffled[start : start + config.batch_size]
                    loss = _mean_distance(self.predictor, x[batch], y[batch])
                    optimizer.zero_grad(set_to_none=True)
                    loss.backward()
                    optimizer.step()
                    total += float(loss.detach()) * batch.shape[0]
                schedule.step()
                self.predictor.eval()
                with torch.no_grad():
                    val_loss = float(_mean_distance(self.predictor, x[val_idx], y[val_idx]))
                if val_loss < best_loss:
                    best_loss, stale = val_loss, 0
                    best_state = {k: v.detach().clone() for k, v in self.predictor.state_dict().items()}
                else:
                    stale += 1
                report = TrainProgress(epoch + 1, config.max_epochs, total / train_idx.shape[0], val_loss, best_loss)
                LOG.debug("RND-OE epoch %d train %.5f val %.5f", epoch + 1, report.train_loss, val_loss)
                if progress is not None:
                    progress(report)
                if stale >= config.patience:
                    LOG.info("RND-OE early stop after %d epochs (best val %.5f)", epoch + 1, best_loss)
                    break
        if best_state is not None:
            self.predictor.load_state_dict(best_state)
        self.predictor.eval()
        self._cache_numpy()

    def score(self, batch: np.ndarray) -> np.ndarray:
        """RND-OE scores ``[N]`` of embeddings ``[N, E]`` with torch (eq. 1)."""
        x = torch.from_numpy(self._check_batch(batch))
        with torch.no_grad():
            return torch.linalg.vector_norm(self.predictor(x) - self.target(x), dim=1).double().numpy()

    def score_one(self, x: np.ndarray) -> float:
        """RND-OE score of one embedding ``[E]`` with the cached numpy float32 weights (eq. 1).

        Where float32 overflows (an activation beyond 3.4e38, or ``inf - inf`` in the difference), the
        score is computed again in float64, which holds every finite float32 input; a score that is still
        not finite is returned as such for the caller to reject (:func:`fiper_ros.core.scores.obs_score`).
        """
        x = np.asarray(x, dtype=np.float32)
        if x.shape != (self.embedding_dim,):
            raise RNDError(f"expected one embedding of shape ({self.embedding_dim},), got {x.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            diff = self._np_predictor(x) - self._np_target(x)
            score = float(np.sqrt(np.dot(diff, diff)))
            if not np.isfinite(score):
                diff = self._np_predictor(x, np.float64) - self._np_target(x, np.float64)
                score = float(np.sqrt(np.dot(diff, diff)))
        return score

    def digest(self) -> str:
        """SHA-256 over both networks' weights."""
        return state_digest(self.target, self.predictor)

    def save(self, directory: str | Path) -> None:
        """Write ``rnd_oe.pt`` (both state dicts) and ``rnd_oe.json`` (dimension, config, seed)."""
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        state = {"target": self.target.state_dict(), "predictor": self.predictor.state_dict()}
        torch.save(state, directory / WEIGHTS_FILE)
        meta = {"embedding_dim": self.embedding_dim, "seed": self.seed, "config": self.config.to_dict()}
        (directory / CONFIG_FILE).write_text(json.dumps(meta, indent=2) + "\n")

    @classmethod
    def load(cls, directory: str | Path) -> RNDOE:
        """Read a model written by :meth:`save`."""
        directory = Path(directory)
        for name in (WEIGHTS_FILE, CONFIG_FILE):
            if not (directory / name).is_file():
                raise RNDError(f"RND-OE model file missing: {directory / name}")
        meta = json.loads((directory / CONFIG_FILE).read_text())
        model = cls(meta["embedding_dim"], RNDConfig.from_dict(meta["config"]), meta["seed"])
        try:
            state = torch.load(directory / WEIGHTS_FILE, map_location="cpu", weights_only=True)
            model.target.load_state_dict(state["target"])
            model.predictor.load_state_dict(state["predictor"])
        except (KeyError, RuntimeError, EOFError, pickle.UnpicklingError) as error:
            raise RNDError(f"{directory / WEIGHTS_FILE}: unreadable or not matching {CONFIG_FILE}: {error}") from error
        model._cache_numpy()
        return model
