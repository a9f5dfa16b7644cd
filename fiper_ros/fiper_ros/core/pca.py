"""Mean-centred principal components of observation embeddings, shared by the embedding-space detectors.

The embeddings ``x [N, E]`` (float64) are centred on their mean and the first ``components`` right singular
vectors of the centred matrix are the basis; ``components`` is capped at ``min(E, N - 1)`` (the rank the
centred data can have) and is at least 1. Centring matters: FAIL-Detect's re-implementation of PCA-kmeans
skips it, which turns the first component towards the mean instead of the largest variance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class PCA:
    """A fitted projection: ``mean [E]`` and the orthonormal ``basis [k, E]`` (rows: components, largest
    variance first)."""

    mean: np.ndarray
    basis: np.ndarray

    @classmethod
    def fit(cls, x: np.ndarray, components: int) -> PCA:
        """The first ``components`` (capped, see the module docstring) principal components of ``x [N, E]``,
        which the caller has checked to be finite with ``N >= 1``."""
        x = np.asarray(x, dtype=np.float64)
        mean = x.mean(axis=0)
        _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
        rank = max(1, min(components, vt.shape[0], x.shape[0] - 1))
        return cls(mean, vt[:rank])

    def project(self, x: np.ndarray) -> np.ndarray:
        """Coordinates ``[..., k]`` of embeddings ``[..., E]``: ``(x - mean) @ basis.T`` in float64."""
        return (np.asarray(x, dtype=np.float64) - self.mean) @ self.basis.T
