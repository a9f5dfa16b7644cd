"""Training RND-OE with torch (App. A.2), and reading the torch weights of calibration format 1.

Training (App. A.2, training-parameter table): AdamW (lr 1e-4, weight decay 1e-5, eps 1e-8), cosine
schedule to 1e-6, batch 256, at most 250 epochs, early stopping with patience 7 on a 0.9/0.1
train/validation split. :func:`fit_rnd` returns the trained model as :class:`fiper_ros.core.rnd_oe.RNDOE`,
which scores in numpy: only calibration (``fiper calibrate``), the evaluation and the baselines import
torch, never the scoring nodes.
"""

from __future__ import annotations

import logging
import pickle
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fiper_ros.core.rnd_oe import (LEGACY_WEIGHTS_FILE, NETWORKS, RNDOE, ProgressCallback, RNDConfig, RNDError,
                                   TrainProgress, check_embeddings)
from fiper_ros.core.torch_mlp import build_mlp, deterministic, parameters_of, train_epoch

LOG = logging.getLogger(__name__)


def _adamw(params: Any, config: RNDConfig) -> torch.optim.AdamW:
    kwargs = {"lr": config.lr, "weight_decay": config.weight_decay, "eps": config.eps}
    try:
        return torch.optim.AdamW(params, fused=True, **kwargs)
    except (RuntimeError, TypeError):
        return torch.optim.AdamW(params, **kwargs)


def _mean_distance(predictor: torch.nn.Module, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
    """Training loss (eq. 1): the mean over samples of ``||f(x) - g(x)||_2``, ``y = g(x)``."""
    return torch.linalg.vector_norm(predictor(x) - y, dim=1).mean()


class TorchRND:
    """Target and predictor as torch networks: the orthogonal initialisation and the training loop.

    RND-A (:mod:`fiper_ros.baselines.rnd_a`) replaces both networks with its chunk networks and keeps the
    loop and the batch :meth:`score`.
    """

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

    def train(self, embeddings: np.ndarray, progress: ProgressCallback | None = None) -> None:
        """Train the predictor in place; deterministic for a fixed seed on a fixed machine."""
        x = torch.from_numpy(check_embeddings(embeddings, self.embedding_dim))
        if x.shape[0] < 2:
            raise RNDError(f"RND-OE training needs at least 2 samples, got {x.shape[0]}")
        config = self.config
        generator = torch.Generator().manual_seed(self.seed + 1)
        with deterministic(), torch.no_grad():
            y = self.target(x)
        order = torch.randperm(x.shape[0], generator=generator)
        n_val = min(max(1, round(config.val_fraction * x.shape[0])), x.shape[0] - 1)
        val_idx, train_idx = order[:n_val], order[n_val:]
        optimizer = _adamw(self.predictor.parameters(), config)
        schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, T_max=config.max_epochs, eta_min=config.lr_min)
        best_loss, best_state, stale = float("inf"), None, 0
        with deterministic():
            for epoch in range(config.max_epochs):
                self.predictor.train()
                shuffled = train_idx[torch.randperm(train_idx.shape[0], generator=generator)]
                train_loss = train_epoch(optimizer, shuffled, config.batch_size,
                                         lambda batch: _mean_distance(self.predictor, x[batch], y[batch]))
                schedule.step()
                self.predictor.eval()
                with torch.no_grad():
                    val_loss = float(_mean_distance(self.predictor, x[val_idx], y[val_idx]))
                if val_loss < best_loss:
                    best_loss, stale = val_loss, 0
                    best_state = {k: v.detach().clone() for k, v in self.predictor.state_dict().items()}
                else:
                    stale += 1
                report = TrainProgress(epoch + 1, config.max_epochs, train_loss, val_loss, best_loss)
                LOG.debug("RND-OE epoch %d train %.5f val %.5f", epoch + 1, report.train_loss, val_loss)
                if progress is not None:
                    progress(report)
                if stale >= config.patience:
                    LOG.info("RND-OE early stop after %d epochs (best val %.5f)", epoch + 1, best_loss)
                    break
        if best_state is not None:
            self.predictor.load_state_dict(best_state)
        self.predictor.eval()

    def score(self, batch: np.ndarray) -> np.ndarray:
        """RND scores ``[N]`` of inputs ``[N, E]`` with torch (eq. 1)."""
        x = torch.from_numpy(check_embeddings(batch, self.embedding_dim))
        with torch.no_grad():
            return torch.linalg.vector_norm(self.predictor(x) - self.target(x), dim=1).double().numpy()

    def numpy(self) -> RNDOE:
        """The model as it scores: both networks' parameters handed to :class:`RNDOE`."""
        return RNDOE(self.embedding_dim, self.config, self.seed, parameters_of(self.target),
                     parameters_of(self.predictor))


def untrained_rnd(embedding_dim: int, config: RNDConfig | None = None, seed: int = 0) -> RNDOE:
    """An RND-OE model as initialised, before training (the per-step cost does not depend on training)."""
    return TorchRND(embedding_dim, config, seed).numpy()


def fit_rnd(embeddings: np.ndarray, config: RNDConfig | None = None, seed: int = 0,
            progress: ProgressCallback | None = None) -> RNDOE:
    """Train a predictor on ID embeddings ``[N, E]`` (every policy step is one sample); deterministic for a
    fixed seed on a fixed machine."""
    model = TorchRND(np.asarray(embeddings).shape[-1], config, seed)
    model.train(embeddings, progress)
    return model.numpy()


def read_legacy(directory: Path, embedding_dim: int, config: RNDConfig, seed: int) -> RNDOE:
    """The model of a calibration of format 1, whose weights are the torch file ``rnd_oe.pt`` (both state
    dicts), described by ``embedding_dim``, ``config`` and ``seed``."""
    path = directory / LEGACY_WEIGHTS_FILE
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
        networks = [{name: tensor.numpy() for name, tensor in state[network].items()} for network in NETWORKS]
    except (KeyError, TypeError, AttributeError, RuntimeError, EOFError, pickle.UnpicklingError) as error:
        raise RNDError(f"{path}: unreadable or not matching its description: {type(error).__name__}: {error}") \
            from error
    return RNDOE(embedding_dim, config, seed, *networks)
