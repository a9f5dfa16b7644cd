"""PCA-kmeans: distance to the nearest k-means centroid in a PCA space of observation embeddings
(Liu et al., "Multi-Task Interactive Robot Fleet Learning with Visual World Models", CoRL 2024;
re-implemented for the policy's embedding space as in App. B.5 of the FIPER paper).

Fitting, on the embeddings of all steps of the successful calibration rollouts:

1. PCA: the embeddings are centred on their mean (FAIL-Detect's re-implementation skips this,
   which makes the first component point at the mean instead of the largest variance; we do not copy
   that bug) and projected on the first ``components`` right singular vectors.
2. k-means with ``clusters`` centroids (64 as in the paper; fewer when there are fewer distinct
   samples): k-means++ initialisation and Lloyd iterations, seeded, in numpy.

Score of a step: Euclidean distance of its projected embedding to the nearest centroid.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Self

import numpy as np

from fiper_ros.baselines.base import BaselineError, training_rollouts
from fiper_ros.core.rollout import Rollout

LOG = logging.getLogger(__name__)

MODEL_FILE = "pca_kmeans.npz"


@dataclass(frozen=True)
class PCAKMeansConfig:
    """Hyperparameters: PCA ``components`` (capped at the data rank), ``clusters``, Lloyd iterations."""

    components: int = 32
    clusters: int = 64
    max_iterations: int = 100
    tolerance: float = 1e-6


def _squared_distances(x: np.ndarray, centroids: np.ndarray) -> np.ndarray:
    """``||x_i - c_j||^2`` ``[N, K]``, clipped at 0 against rounding."""
    d2 = np.sum(x * x, axis=1)[:, None] - 2.0 * x @ centroids.T + np.sum(centroids * centroids, axis=1)[None, :]
    return np.maximum(d2, 0.0)


def kmeans_plus_plus(x: np.ndarray, clusters: int, rng: np.random.Generator) -> np.ndarray:
    """k-means++ seeding: each new centroid drawn with probability proportional to ``D(x)^2``."""
    centroids = [x[rng.integers(x.shape[0])]]
    closest = _squared_distances(x, centroids[0][None, :])[:, 0]
    for _ in range(1, clusters):
        total = closest.sum()
        if total <= 0.0:  # every sample already coincides with a centroid
            break
        index = rng.choice(x.shape[0], p=closest / total)
        centroids.append(x[index])
        closest = np.minimum(closest, _squared_distances(x, x[index][None, :])[:, 0])
    return np.array(centroids)


def kmeans(x: np.ndarray, clusters: int, seed: int, max_iterations: int = 100, tolerance: float = 1e-6) -> np.ndarray:
    """Centroids ``[K, F]`` of ``x [N, F]`` (k-means++ then Lloyd); ``K <= min(clusters, N)``.

    An empty cluster keeps its previous centroid. Stops when no centroid moves by more than
    ``tolerance`` times the data scale, or after ``max_iterations``.
    """
    rng = np.random.default_rng(seed)
    centroids = kmeans_plus_plus(x, min(clusters, x.shape[0]), rng)
    scale = max(float(np.max(np.abs(x))), 1e-12)
    for iteration in range(max_iterations):
        labels = np.argmin(_squared_distances(x, centroids), axis=1)
        counts = np.bincount(labels, minlength=centroids.shape[0])
        sums = np.zeros_like(centroids)
        np.add.at(sums, labels, x)
        updated = np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], centroids)
        shift = float(np.max(np.abs(updated - centroids)))
        centroids = updated
        if shift <= tolerance * scale:
            LOG.debug("k-means converged after %d iterations", iteration + 1)
            break
    return centroids


class PCAKMeans:
    """PCA-kmeans as a :class:`~fiper_ros.baselines.base.Baseline`."""

    name = "pca_kmeans"

    def __init__(self, config: PCAKMeansConfig | None = None) -> None:
        self.config = config or PCAKMeansConfig()
        self.mean: np.ndarray | None = None
        self.components: np.ndarray | None = None
        self.centroids: np.ndarray | None = None

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """PCA and k-means on every step's embedding of the successful rollouts."""
        x = np.concatenate([r.embeddings for r in training_rollouts(rollouts)]).astype(np.float64)
        self.mean = x.mean(axis=0)
        centred = x - self.mean
        _, _, vt = np.linalg.svd(centred, full_matrices=False)
        rank = max(1, min(self.config.components, vt.shape[0], x.shape[0] - 1))
        self.components = vt[:rank]
        self.centroids = kmeans(
            centred @ self.components.T, self.config.clusters, seed, self.config.max_iterations, self.config.tolerance
        )
        LOG.info("PCA-kmeans: %d components, %d centroids from %d steps", rank, self.centroids.shape[0], x.shape[0])
        return self

    def project(self, embeddings: np.ndarray) -> np.ndarray:
        """Mean-centred PCA coordinates ``[N, k]`` of embeddings ``[N, E]``."""
        if self.mean is None or self.components is None:
            raise BaselineError("PCA-kmeans is not fitted")
        return (np.asarray(embeddings, dtype=np.float64) - self.mean) @ self.components.T

    def scores(self, rollout: Rollout) -> np.ndarray:
        """Distance of each step's projected embedding to its nearest centroid."""
        if self.centroids is None:
            raise BaselineError("PCA-kmeans is not fitted")
        return np.sqrt(np.min(_squared_distances(self.project(rollout.embeddings), self.centroids), axis=1))

    def save(self, directory: str | Path) -> None:
        """Write ``pca_kmeans.npz`` (mean, components, centroids, config)."""
        if self.centroids is None or self.mean is None or self.components is None:
            raise BaselineError("PCA-kmeans is not fitted")
        directory = Path(directory)
        directory.mkdir(parents=True, exist_ok=True)
        np.savez(directory / MODEL_FILE, mean=self.mean, components=self.components, centroids=self.centroids,
                 config=np.array(json.dumps(asdict(self.config))))

    @classmethod
    def load(cls, directory: str | Path) -> PCAKMeans:
        """Read a model written by :meth:`save`."""
        path = Path(directory) / MODEL_FILE
        if not path.is_file():
            raise BaselineError(f"PCA-kmeans model file missing: {path}")
        with np.load(path, allow_pickle=False) as data:
            model = cls(PCAKMeansConfig(**json.loads(str(data["config"]))))
            model.mean, model.components, model.centroids = data["mean"], data["components"], data["centroids"]
        return model
