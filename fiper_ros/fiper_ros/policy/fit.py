"""Open-loop fit: how far a policy's sampled chunks are from the expert's on demonstration states.

A policy that fails in closed loop is either underfitted (its chunks already miss the expert's on the
states it was trained on) or meets states it never saw. This check tells the two apart: at states ``t``
of demonstration episodes it samples ``B`` chunks from the observation history of that state and compares
their mean with the expert's chunk, both as :func:`.dataset.sample_indices` gives them to training.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from .dataset import sample_indices
from .encoder import CAMERAS
from .errors import PolicyError
from .policy import Policy


@dataclass(frozen=True)
class FitReport:
    """Per action dimension, averaged over the visited states (all float ``[D]``)."""

    states: int
    error: np.ndarray
    """Mean absolute difference between the mean of the ``B`` sampled chunks and the expert's chunk."""
    spread: np.ndarray
    """Mean standard deviation over the ``B`` sampled chunks."""
    magnitude: np.ndarray
    """Mean absolute expert action (the scale ``error`` is to be read against)."""


def open_loop_fit(policy: Policy, episodes: list[Path], batch: int = 16, stride: int = 1,
                  seed: int = 0) -> FitReport:
    """Compare ``policy`` with the expert at every ``stride``-th state of each episode file.

    The noise of each state comes from ``torch.Generator().manual_seed(seed)``, so a report is a function
    of its arguments. A ``stride`` below 1 or episodes without a state are a :class:`PolicyError`.
    """
    if stride < 1:
        raise PolicyError(f"stride must be >= 1, got {stride}")
    errors, spreads, magnitudes = [], [], []
    config = policy.config
    for path in episodes:
        with np.load(path) as data:
            frames = {key: data[key] for key in (*CAMERAS, "proprio")}
            actions = np.asarray(data["actions"], dtype=np.float32)
        history_index, chunk_index = sample_indices(len(actions), config.obs_horizon, config.horizon)
        for t in range(0, len(actions), stride):
            history = [{key: frames[key][k] for key in frames} for k in history_index[t]]
            _, chunks = policy.act(history, batch, torch.Generator().manual_seed(seed))
            errors.append(np.abs(chunks.mean(axis=0) - actions[chunk_index[t]]).mean(axis=0))
            spreads.append(chunks.std(axis=0).mean(axis=0))
        magnitudes.append(actions)
    if not errors:
        raise PolicyError("no demonstration states to compare")
    return FitReport(len(errors), np.mean(errors, axis=0), np.mean(spreads, axis=0),
                     np.abs(np.concatenate(magnitudes)).mean(axis=0))
