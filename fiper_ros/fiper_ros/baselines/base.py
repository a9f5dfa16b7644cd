"""The interface every baseline implements."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Protocol, Self

import numpy as np
import torch

from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.errors import FiperError


class BaselineError(FiperError):
    """A baseline cannot be fitted or applied."""


class Baseline(Protocol):
    """A failure-prediction score fitted on successful calibration rollouts."""

    name: str

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """Fit on the rollouts with ``success is True`` (others are ignored); returns ``self``."""
        ...

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Per-step scores ``[T]`` (float64, >= 0, larger = more anomalous)."""
        ...


def training_rollouts(rollouts: Sequence[Rollout], minimum: int = 1) -> list[Rollout]:
    """The successful rollouts of ``rollouts``; raises :class:`BaselineError` when fewer than ``minimum``."""
    good = successful(list(rollouts))
    if len(good) < minimum:
        raise BaselineError(f"baseline needs at least {minimum} successful calibration rollouts, got {len(good)}")
    return good


def write_model(directory: str | Path, weights_file: str, state: dict[str, Any], config_file: str,
                meta: dict[str, Any]) -> None:
    """Save torch ``state`` to ``weights_file`` and ``meta`` as JSON to ``config_file`` in ``directory``."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    torch.save(state, directory / weights_file)
    (directory / config_file).write_text(json.dumps(meta, indent=2) + "\n")


def read_model(directory: str | Path, weights_file: str, config_file: str, what: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """Inverse of :func:`write_model`: ``(state, meta)``; :class:`BaselineError` names a missing file."""
    directory = Path(directory)
    for name in (weights_file, config_file):
        if not (directory / name).is_file():
            raise BaselineError(f"{what} model file missing: {directory / name}")
    meta = json.loads((directory / config_file).read_text())
    return torch.load(directory / weights_file, map_location="cpu", weights_only=True), meta
