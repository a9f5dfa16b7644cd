"""Score aggregation over policy timesteps, eqs. (2) and (5).

``eta(t) = sum_{k=0}^{min(w-1, t/h)} s(t - kh)``: a trailing sum over the last ``w`` policy steps,
with partial sums while fewer than ``w`` steps exist. Scores here are indexed by policy step, so the
stride ``h`` is implicit. The paper's ablations also use the cumulative sum (``w = inf``) and the
single-step score (``w = 1``). Max-pooling (``"max"``) takes the largest of the last ``w`` scores instead of
their sum: one high step counts as much as a run of them, so a short burst is not diluted by the window.

The vectorised functions and :class:`WindowAccumulator` add the same float64 numbers in the same
order (newest score first), so they agree bit for bit; the monitor relies on that (a maximum has no rounding). A window never
holds a non-finite score (one NaN would spoil the next ``w`` sums, or all later cumulative ones): both
refuse it with ``ValueError``. A step whose score is missing enters as 0 (:meth:`WindowAccumulator.skip`).
"""

from __future__ import annotations

import math
from collections import deque

import numpy as np

MODES = ("window", "cumulative", "single", "max")


def _scores(scores: np.ndarray) -> np.ndarray:
    array = np.asarray(scores, dtype=np.float64)
    if array.ndim != 1:
        raise ValueError(f"scores must be 1-D, got shape {array.shape}")
    if not np.isfinite(array).all():
        raise ValueError(f"scores must be finite, got {int(np.count_nonzero(~np.isfinite(array)))} NaN/inf")
    return array


def _check_window(w: int) -> int:
    if int(w) != w or w < 1:
        raise ValueError(f"window size must be an integer >= 1, got {w}")
    return int(w)


def windowed(scores: np.ndarray, w: int) -> np.ndarray:
    """Trailing window sums of ``scores[T]`` (eq. 2/5); same length, partial sums for ``t < w``."""
    s = _scores(scores)
    w = _check_window(w)
    out = s.copy()
    for k in range(1, min(w, s.shape[0])):
        out[k:] += s[:-k]
    return out


def max_pooled(scores: np.ndarray, w: int) -> np.ndarray:
    """Trailing maxima of ``scores[T]`` over the last ``w`` steps; same length, fewer steps while ``t < w``."""
    s = _scores(scores)
    w = _check_window(w)
    out = s.copy()
    for k in range(1, min(w, s.shape[0])):
        np.maximum(out[k:], s[:-k], out=out[k:])
    return out


def cumulative(scores: np.ndarray) -> np.ndarray:
    """Cumulative sums of ``scores[T]`` (the window ``w = inf``)."""
    return np.cumsum(_scores(scores))


def aggregate(scores: np.ndarray, mode: str = "window", w: int = 1) -> np.ndarray:
    """``windowed`` (mode ``"window"``), ``max_pooled`` (``"max"``), ``cumulative`` or the raw scores
    (``"single"``) as float64."""
    if mode == "window":
        return windowed(scores, w)
    if mode == "max":
        return max_pooled(scores, w)
    if mode == "cumulative":
        return cumulative(scores)
    if mode == "single":
        return _scores(scores).copy()
    raise ValueError(f"unknown aggregation mode {mode!r}; expected one of {MODES}")


class WindowAccumulator:
    """Streaming form of :func:`aggregate`: ``push(score)`` returns ``eta(t)`` for the newest step."""

    def __init__(self, w: int = 1, mode: str = "window") -> None:
        if mode not in MODES:
            raise ValueError(f"unknown aggregation mode {mode!r}; expected one of {MODES}")
        self.mode = mode
        self.w = _check_window(w) if mode in ("window", "max") else 1
        self._recent: deque[float] = deque(maxlen=self.w)
        self._total = 0.0

    def reset(self) -> None:
        """Forget all scores (start of a new rollout)."""
        self._recent.clear()
        self._total = 0.0

    def skip(self, steps: int) -> None:
        """Enter ``steps`` missing steps as scores of 0, in O(min(steps, w)): only the last ``w`` matter."""
        if steps < 0:
            raise ValueError(f"cannot skip {steps} steps")
        if self.mode != "cumulative":  # a cumulative sum is unchanged by zeros
            self._recent.extend([0.0] * min(steps, self.w))

    def push(self, score: float) -> float:
        """Add the score of the next policy step and return its aggregated value."""
        score = float(score)
        if not math.isfinite(score):
            raise ValueError(f"a non-finite score ({score}) never enters the window")
        if self.mode == "cumulative":
            self._total += score
            return self._total
        self._recent.append(score)
        if self.mode == "max":
            return max(self._recent)
        total = self._recent[-1]
        for k in range(2, len(self._recent) + 1):
            total += self._recent[-k]
        return total
