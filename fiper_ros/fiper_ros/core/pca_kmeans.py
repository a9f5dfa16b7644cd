"""PCA-kmeans: distance to the nearest k-means centroid in a PCA space of observation embeddings
(Liu et al., "Multi-Task Interactive Robot Fleet Learning with Visual World Models", CoRL 2024;
re-implemented for the policy's embedding space as in App. B.5 of the FIPER paper).

Fitting, on the embeddings of all steps of the successful calibration rollouts:

1. PCA: the embeddings are centred on their mean and projected on the first ``components`` right singular
   vectors (:class:`fiper_ros.core.pca.PCA`; FAIL-Detect's re-implementation skips the centring, which makes the
   first component point at the mean instead of the largest variance; we do not copy that bug).
2. k-means with ``clusters`` centroids (64 as in the paper; fewer when there are fewer distinct
   samples): k-means++ initialisation and Lloyd iterations, seeded, in numpy.

Score of a step: Euclidean distance of its projected embedding to the nearest centroid (exact differences, in
float64), computed step by step (:meth:`PCAKMeans.score_one`; a whole rollout with the same function, so both
agree bit for bit). Per-step cost ``O(E k + K k)``. Stored as ``pca_kmeans.json`` + ``pca_kmeans.npz``
(:mod:`fiper_ros.core.detector_model`), numpy only.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar, Self

import numpy as np

from fiper_ros.core.detector_model import EmbeddingDetector, check_input
from fiper_ros.core.errors import CoreError
from fiper_ros.core.pca import PCA
from fiper_ros.core.rollout import Rollout, successful

LOG = logging.getLogger(__name__)


class PCAKMeansError(CoreError):
    """Bad PCA-kmeans input (shape, NaN/inf), model files, or no successes to fit on."""


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


class PCAKMeans(EmbeddingDetector):
    """PCA-kmeans as a :class:`~fiper_ros.baselines.base.Baseline` and a core detector: :meth:`fit` on the
    successes, :meth:`score_one` / :meth:`scores`, :meth:`save` / :meth:`load`."""

    name: ClassVar[str] = "pca_kmeans"
    format_version: ClassVar[int] = 1
    error: ClassVar[type[ValueError]] = PCAKMeansError

    def __init__(self, config: PCAKMeansConfig | None = None) -> None:
        self.config = config or PCAKMeansConfig()
        self.seed = 0
        self.pca: PCA | None = None
        self.centroids: np.ndarray | None = None

    def fit(self, rollouts: Sequence[Rollout], seed: int = 0) -> Self:
        """PCA and k-means on every step's embedding of the rollouts with ``success is True`` (others ignored; at
        least one)."""
        good = successful(list(rollouts))
        if not good:
            raise PCAKMeansError("PCA-kmeans is fitted on successful rollouts: none given")
        x = np.concatenate([r.embeddings for r in good]).astype(np.float64)
        pca = PCA.fit(x, self.config.components)
        centroids = kmeans(pca.project(x), self.config.clusters, seed, self.config.max_iterations,
                           self.config.tolerance)
        self._set(seed, pca, centroids)
        LOG.info("PCA-kmeans: %d components, %d centroids from %d steps", pca.basis.shape[0], centroids.shape[0],
                 x.shape[0])
        return self

    def _set(self, seed: int, pca: PCA, centroids: np.ndarray) -> None:
        dim, k = pca.mean.shape[0], pca.basis.shape[0]
        if pca.mean.ndim != 1 or pca.basis.shape != (k, dim) or centroids.ndim != 2 or centroids.shape[1] != k \
                or centroids.shape[0] < 1:
            raise PCAKMeansError(f"mean {pca.mean.shape}, basis {pca.basis.shape} and centroids {centroids.shape} "
                                 "do not fit together")
        if not all(np.isfinite(a).all() for a in (pca.mean, pca.basis, centroids)):
            raise PCAKMeansError("a model array holds NaN/inf")
        self.seed, self.pca, self.centroids = int(seed), pca, np.asarray(centroids, dtype=np.float64)

    @property
    def embedding_dim(self) -> int:
        """``E``, the embedding size the model was fitted on (0 before fitting)."""
        return 0 if self.pca is None else int(self.pca.mean.shape[0])

    def _input(self, embeddings: np.ndarray, shape: tuple[int | str, ...]) -> np.ndarray:
        """Checked embeddings of ``shape``."""
        if self.pca is None:
            raise PCAKMeansError("PCA-kmeans is not fitted")
        return check_input(embeddings, shape, "embeddings", PCAKMeansError)

    def _score(self, x: np.ndarray) -> float:
        """Distance of one checked embedding ``[E]`` to its nearest centroid: the one scoring function."""
        assert self.pca is not None and self.centroids is not None
        with np.errstate(over="ignore", invalid="ignore"):
            point = self.pca.project(x)
            score = float(np.sqrt(np.min(np.square(self.centroids - point).sum(axis=1))))
        if not np.isfinite(score):
            raise PCAKMeansError("the embedding is too large to score in float64")
        return score

    def describe(self) -> dict[str, Any]:
        """Configuration, seed and embedding size (the JSON description of the model)."""
        return {"config": asdict(self.config), "seed": self.seed, "embedding_dim": self.embedding_dim}

    def arrays(self) -> dict[str, np.ndarray]:
        """``mean [E]``, ``basis [k, E]`` (the principal components) and ``centroids [K, k]``."""
        if self.pca is None or self.centroids is None:
            raise PCAKMeansError("PCA-kmeans is not fitted")
        return {"mean": self.pca.mean, "basis": self.pca.basis, "centroids": self.centroids}

    @classmethod
    def from_stored(cls, description: dict[str, Any], arrays: dict[str, np.ndarray]) -> PCAKMeans:
        """The model of a :meth:`describe` output and its :meth:`arrays` (:meth:`load` reads them)."""
        model = cls(PCAKMeansConfig(**description["config"]))
        model._set(description["seed"], PCA(arrays["mean"], arrays["basis"]), arrays["centroids"])
        if model.embedding_dim != description["embedding_dim"]:
            raise PCAKMeansError(f"embedding_dim {description['embedding_dim']}, but arrays of {model.embedding_dim}")
        return model
