"""Min-max normalisation to [-1, 1] with statistics from the demonstrations (saved with the model)."""
from __future__ import annotations

import numpy as np
import torch
from torch import nn

_MIN_RANGE = 1e-2
"""Dimensions whose demo range is smaller than this use this range instead: near-constant inputs (e.g. the
fixed TCP height) must not amplify small deviations, and nothing is divided by 0."""


class RangeNormalizer(nn.Module):
    """Affine map ``x -> 2 (x - mid) / (high - low)``, ``mid = (low + high) / 2``, per last-axis dimension.

    ``low`` and ``high`` are buffers, so they travel in the state dict.
    """

    def __init__(self, low: np.ndarray, high: np.ndarray) -> None:
        super().__init__()
        low = np.asarray(low, dtype=np.float32)
        high = np.asarray(high, dtype=np.float32)
        if low.shape != high.shape or low.ndim != 1:
            raise ValueError(f"low/high must be vectors of one shape, got {low.shape} and {high.shape}")
        if np.any(high < low):
            raise ValueError("high must be >= low")
        self.register_buffer("low", torch.from_numpy(low))
        self.register_buffer("high", torch.from_numpy(high))

    @classmethod
    def fit(cls, data: np.ndarray) -> RangeNormalizer:
        """Statistics over all rows of ``data [..., D]``."""
        flat = np.asarray(data, dtype=np.float64).reshape(-1, np.shape(data)[-1])
        return cls(flat.min(axis=0), flat.max(axis=0))

    def _scale(self) -> torch.Tensor:
        return torch.clamp(self.high - self.low, min=_MIN_RANGE) / 2.0

    def normalize(self, x: torch.Tensor) -> torch.Tensor:
        """Physical units -> [-1, 1] (for data inside the demo range)."""
        return (x - (self.low + self.high) / 2.0) / self._scale()

    def unnormalize(self, x: torch.Tensor) -> torch.Tensor:
        """[-1, 1] -> physical units."""
        return x * self._scale() + (self.low + self.high) / 2.0

    def stats(self) -> dict[str, list[float]]:
        """Plain-list statistics for the model's YAML config."""
        return {"low": self.low.tolist(), "high": self.high.tolist()}
