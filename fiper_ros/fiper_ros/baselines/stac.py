"""STAC: statistical temporal action consistency (Agia et al., "Unpacking Failure Modes of Generative
Policies: Runtime Monitoring of Consistency and Progress", CoRL 2024; App. B.5 of the FIPER paper).

At policy step ``t`` the ``B`` chunks sampled at ``t - 1`` and at ``t`` overlap in ``H - h`` environment
steps: ``prev[:, h:]`` and ``curr[:, :H - h]``. Each sample's overlap is flattened to one vector of
``(H - h) * D`` values and the two sample sets are compared with the biased squared maximum mean
discrepancy

``MMD^2 = mean K(X, X) + mean K(Y, Y) - 2 mean K(X, Y)``,  ``K(a, b) = exp(-gamma ||a - b||^2)``,

with the median heuristic ``gamma = 1 / (2 median)`` over the positive pairwise squared distances of
the pooled ``2B`` samples (as the Sentinel code). The first step of a rollout has no predecessor and
scores 0; a step whose pooled samples all coincide (no positive distance) scores 0 as well.

STAC needs no training. Its original form is the cumulative sum of these scores
(``core.window.aggregate(..., "cumulative")``); the evaluation also runs it windowed and single-step.
Everything is vectorised over steps and samples; only long rollouts are processed in blocks of
steps to bound memory.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Self

import numpy as np

from fiper_ros.baselines.base import BaselineError
from fiper_ros.core.rollout import Rollout

#: Pooled-distance entries per block of steps (float64, 16 MB per intermediate array).
_BLOCK_ENTRIES = 2_000_000


def _median_positive(pairs: np.ndarray) -> np.ndarray:
    """Median of the positive entries of each row ``[S, P]``; NaN for a row without any."""
    out = np.full(pairs.shape[0], np.nan)
    for row, values in enumerate(pairs):
        positive = values[values > 0.0]
        n = positive.size
        if n:
            low, high = (n - 1) // 2, n // 2
            part = np.partition(positive, (low, high))
            out[row] = 0.5 * (part[low] + part[high])
    return out


def _block_scores(prev: np.ndarray, curr: np.ndarray) -> np.ndarray:
    """Biased MMD^2 per step of overlap sets ``prev, curr [S, B, F]`` -> ``[S]``."""
    samples = prev.shape[1]
    pooled = np.concatenate([prev, curr], axis=1)
    norms = np.einsum("sbf,sbf->sb", pooled, pooled)
    distances = np.matmul(pooled, pooled.transpose(0, 2, 1))
    distances *= -2.0
    distances += norms[:, :, None]
    distances += norms[:, None, :]
    np.maximum(distances, 0.0, out=distances)
    upper = np.flatnonzero(np.triu(np.ones((2 * samples, 2 * samples), dtype=bool), k=1))
    median = _median_positive(np.take(distances.reshape(distances.shape[0], -1), upper, axis=1))
    has_positive = ~np.isnan(median)
    gamma = np.where(has_positive, 1.0 / (2.0 * np.where(has_positive, median, 1.0)), 0.0)
    np.multiply(distances, -gamma[:, None, None], out=distances)
    kernel = np.exp(distances, out=distances)
    k_xx = kernel[:, :samples, :samples].mean(axis=(1, 2))
    k_yy = kernel[:, samples:, samples:].mean(axis=(1, 2))
    k_xy = kernel[:, :samples, samples:].mean(axis=(1, 2))
    return np.where(has_positive, np.maximum(k_xx + k_yy - 2.0 * k_xy, 0.0), 0.0)


def check_overlap(exec_steps: int, horizon: int) -> None:
    """Refuse a layout without an overlap of consecutive chunks: STAC needs ``1 <= h < H``."""
    if not 1 <= exec_steps < horizon:
        raise BaselineError(f"STAC needs 1 <= h < H for an overlap, got h={exec_steps}, H={horizon}")


def stac_scores(actions: np.ndarray, exec_steps: int) -> np.ndarray:
    """STAC scores ``[T]`` of a rollout's sampled chunks ``[T, B, H, D]`` with ``h = exec_steps``."""
    actions = np.asarray(actions, dtype=np.float64)
    if actions.ndim != 4:
        raise BaselineError(f"actions must be [T, B, H, D], got shape {actions.shape}")
    steps, samples, horizon, _ = actions.shape
    check_overlap(exec_steps, horizon)
    scores = np.zeros(steps)
    if steps < 2:
        return scores
    prev = actions[:-1, :, exec_steps:, :].reshape(steps - 1, samples, -1)
    curr = actions[1:, :, : horizon - exec_steps, :].reshape(steps - 1, samples, -1)
    block = max(1, _BLOCK_ENTRIES // (4 * samples * samples))  # (2B)^2 entries per step
    for start in range(0, steps - 1, block):
        stop = min(start + block, steps - 1)
        scores[1 + start : 1 + stop] = _block_scores(prev[start:stop], curr[start:stop])
    return scores


class STAC:
    """STAC as a :class:`~fiper_ros.baselines.base.Baseline` (no parameters to fit)."""

    name = "stac"

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """Nothing to learn: STAC compares consecutive action batches directly."""
        del rollouts, seed
        return self

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Per-step STAC scores of ``rollout``."""
        return stac_scores(rollout.actions, rollout.exec_steps)
