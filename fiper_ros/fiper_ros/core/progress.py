"""Progress: a per-step score that rises when the elapsed time runs ahead of the task's progress.

A policy that stalls, loops or retries keeps producing observations of an early phase of the task while the
time a success needs runs out. Fitted on successful rollouts only (their observation embeddings ``O_t^e``),
the detector estimates the progress of a new embedding from the successes' steps that look like it, and the
score says how far the elapsed share of a typical success is ahead of that estimate:

- **progress of a fit step**: step ``t`` of a fit rollout of ``T`` steps has ``p = t / (T - 1)`` (a one-step
  rollout: ``p = 1``);
- **reference set**: the fit steps' embeddings projected on the first ``components`` mean-centred principal
  components of all fit embeddings (:class:`fiper_ros.core.pca.PCA`), each with its ``p``; beyond
  ``max_reference`` steps, a subsample of ``max_reference`` of them without replacement, seeded by the fit seed,
  kept in the fit order. ``L`` is the mean length of the fit rollouts (policy steps);
- **estimated progress** ``p_hat(x)``: the mean ``p`` of the ``neighbours`` references nearest to the projected
  embedding (Euclidean; all of them when there are fewer; a tie at the last place goes to the lower reference
  index);
- **score** at policy step ``t``: ``s(t) = max(0, t / max(L - 1, 1) - p_hat(x_t)) >= 0``, 0 while the policy is on
  pace or ahead of a typical success. Like ``s_RND`` it is aggregated over a window (eqs. 2, 5) and compared
  with a conformal threshold.

Per-step cost: ``O(E k)`` for the projection and ``O(N k)`` for the distances, ``k <= components``,
``N <= max_reference``: bounded by the settings, not by the calibration's size. The whole-rollout form
(:meth:`ProgressDetector.scores`) and the streaming form (:class:`ProgressStream`) score every step with the same
function, so they agree bit for bit. The model is stored as ``progress.json`` + ``progress.npz``
(:mod:`fiper_ros.core.detector_model`) and read with numpy only.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np

from fiper_ros.core.detector_model import StoredModel, check_input
from fiper_ros.core.errors import CoreError
from fiper_ros.core.pca import PCA
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.step_stream import StepStream


class ProgressError(CoreError):
    """Bad input to the progress detector (shape, NaN/inf), bad settings or no successes to fit on."""


@dataclass(frozen=True)
class ProgressSettings:
    """Settings of the progress detector.

    Attributes:
        components: Principal components of the projection (capped at the fit data's rank).
        neighbours: References whose mean progress is the estimate.
        max_reference: Most references kept (a seeded subsample beyond): bounds the per-step cost.
    """

    components: int = 32
    neighbours: int = 5
    max_reference: int = 4096

    def __post_init__(self) -> None:
        for name, value in asdict(self).items():
            if not isinstance(value, int) or isinstance(value, bool) or value < 1:
                raise ProgressError(f"progress setting {name} must be an integer >= 1, got {value!r}")


def step_progress(length: int) -> np.ndarray:
    """Progress ``p = t / (T - 1)`` of the steps ``t = 0 .. T-1`` of a successful rollout of ``T`` steps
    (``[1.0]`` for ``T = 1``)."""
    if length < 1:
        raise ProgressError(f"a rollout has at least one step, got {length}")
    return np.ones(1) if length == 1 else np.arange(length) / (length - 1)


def nearest_mean(reference: np.ndarray, progress: np.ndarray, point: np.ndarray, neighbours: int,
                 work: np.ndarray | None = None) -> float:
    """Mean ``progress`` of the ``neighbours`` rows of ``reference [N, k]`` nearest to ``point [k]`` (squared
    Euclidean distance, exact differences; all rows if ``N <= neighbours``; at a tie for the last place the lower
    row indices win). ``O(N k)``; ``work`` (float64 ``[N, k]``, overwritten) saves allocating the differences."""
    work = np.subtract(reference, point, out=work)
    squared = np.square(work, out=work).sum(axis=1)
    if neighbours >= squared.shape[0]:
        return float(progress.mean())
    last = np.partition(squared, neighbours - 1)[neighbours - 1]
    closer = np.flatnonzero(squared < last)
    tied = np.flatnonzero(squared == last)[: neighbours - closer.size]
    return float(progress[np.sort(np.concatenate([closer, tied]))].mean())


class ProgressDetector(StoredModel):
    """A fitted progress detector (see the module docstring): the projection, the references with their progress
    and the typical length ``L``. Made by :meth:`fit` or :meth:`load` (``progress.json`` + ``progress.npz``, written
    by :meth:`save`); immutable."""

    name: ClassVar[str] = "progress"
    format_version: ClassVar[int] = 1
    error: ClassVar[type[ValueError]] = ProgressError
    #: A score reads the step's own embedding only.
    history: ClassVar[int] = 0

    def __init__(self, settings: ProgressSettings, seed: int, pca: PCA, reference: np.ndarray,
                 reference_progress: np.ndarray, typical_length: float) -> None:
        reference = np.asarray(reference, dtype=np.float64)
        reference_progress = np.asarray(reference_progress, dtype=np.float64)
        dim, k = pca.mean.shape[0], pca.basis.shape[0]
        if pca.basis.shape != (k, dim) or not 1 <= k <= settings.components:
            raise ProgressError(f"projection basis {pca.basis.shape} does not fit embeddings of {dim} and "
                                f"{settings.components} components")
        if reference.ndim != 2 or reference.shape[1] != k or not 1 <= reference.shape[0] <= settings.max_reference:
            raise ProgressError(f"references {reference.shape} are not [N <= {settings.max_reference}, {k}]")
        if reference_progress.shape != reference.shape[:1] or not np.all((reference_progress >= 0)
                                                                         & (reference_progress <= 1)):
            raise ProgressError(f"reference progress must be {reference.shape[:1]} values in [0, 1]")
        if not typical_length >= 1 or not all(np.isfinite(a).all() for a in (pca.mean, pca.basis, reference)):
            raise ProgressError(f"typical length {typical_length} < 1 or a non-finite model array")
        self.settings = settings
        self.seed = int(seed)
        self.pca = pca
        self.reference = reference
        self.reference_progress = reference_progress
        self.typical_length = float(typical_length)
        self._pace = 1.0 / max(self.typical_length - 1.0, 1.0)

    @property
    def embedding_dim(self) -> int:
        """``E``, the embedding size the detector was fitted on."""
        return int(self.pca.mean.shape[0])

    @classmethod
    def fit(cls, rollouts: Sequence[Rollout], settings: ProgressSettings | None = None,
            seed: int = 0) -> ProgressDetector:
        """Fit on the rollouts with ``success is True`` (others are ignored; at least one, all of one embedding
        size): the projection on all their steps, the seeded reference subsample, ``L``."""
        settings = settings or ProgressSettings()
        good = successful(list(rollouts))
        if not good:
            raise ProgressError("the progress detector is fitted on successful rollouts: none given")
        dims = {r.embeddings.shape[1] for r in good}
        if len(dims) != 1:
            raise ProgressError(f"the successes have different embedding sizes {sorted(dims)}")
        x = np.concatenate([r.embeddings for r in good]).astype(np.float64)
        progress = np.concatenate([step_progress(r.length) for r in good])
        pca = PCA.fit(x, settings.components)
        kept = np.arange(x.shape[0])
        if x.shape[0] > settings.max_reference:
            kept = np.sort(np.random.default_rng(seed).choice(x.shape[0], settings.max_reference, replace=False))
        typical = float(np.mean([r.length for r in good]))
        return cls(settings, seed, pca, pca.project(x[kept]), progress[kept], typical)

    def estimate(self, embedding: np.ndarray) -> float:
        """Estimated progress ``p_hat`` in [0, 1] of one embedding ``[E]``."""
        x = check_input(embedding, (self.embedding_dim,), "an embedding", ProgressError)
        return self._estimate(x, self.workspace())

    def workspace(self) -> np.ndarray:
        """A buffer for the distances of one step to every reference (a stream keeps one: no allocation of
        ``N k`` floats per step)."""
        return np.empty_like(self.reference)

    def _estimate(self, x: np.ndarray, work: np.ndarray) -> float:
        with np.errstate(over="ignore", invalid="ignore"):
            point = self.pca.project(x)
        if not np.isfinite(point).all():
            raise ProgressError("the embedding is too large to project in float64")
        return nearest_mean(self.reference, self.reference_progress, point, self.settings.neighbours, work)

    def _score(self, step: int, x: np.ndarray, work: np.ndarray) -> float:
        """``s(t) = max(0, t / max(L - 1, 1) - p_hat(x_t))`` of policy step ``step`` with the checked embedding
        ``x [E]`` (``work``: :meth:`workspace`): the one scoring function of both forms."""
        return max(0.0, step * self._pace - self._estimate(x, work))

    def scores(self, embeddings: np.ndarray) -> np.ndarray:
        """``s(t)`` ``[T]`` (float64) of a whole rollout's embeddings ``[T, E]``, step by step with the streaming
        form's function."""
        x = check_input(embeddings, ("T", self.embedding_dim), "embeddings", ProgressError)
        work = self.workspace()
        return np.array([self._score(t, row, work) for t, row in enumerate(x)], dtype=np.float64)

    def stream(self) -> ProgressStream:
        """A streaming form of this detector, at step 0."""
        return ProgressStream(self)

    def describe(self) -> dict[str, Any]:
        """Settings, seed, embedding size and ``L`` (the JSON description of the model)."""
        return {"settings": asdict(self.settings), "seed": self.seed, "embedding_dim": self.embedding_dim,
                "typical_length": self.typical_length}

    def arrays(self) -> dict[str, np.ndarray]:
        """The fitted arrays: ``mean [E]``, ``basis [k, E]``, ``reference [N, k]``, ``reference_progress [N]``."""
        return {"mean": self.pca.mean, "basis": self.pca.basis, "reference": self.reference,
                "reference_progress": self.reference_progress}

    @classmethod
    def from_stored(cls, description: dict[str, Any], arrays: dict[str, np.ndarray]) -> ProgressDetector:
        """The detector of a :meth:`describe` output and its :meth:`arrays` (:meth:`load` reads them)."""
        detector = cls(ProgressSettings(**description["settings"]), description["seed"],
                       PCA(arrays["mean"], arrays["basis"]), arrays["reference"], arrays["reference_progress"],
                       description["typical_length"])
        if detector.embedding_dim != description["embedding_dim"]:
            raise ProgressError(f"embedding_dim {description['embedding_dim']}, but arrays of "
                                f"{detector.embedding_dim}")
        return detector


class ProgressStream(StepStream):
    """The streaming form: :meth:`update` scores policy steps ``0, 1, 2, ...`` of one rollout (lost steps
    declared with :meth:`skip_to`; a lost step does not change a later score, which reads only its own step:
    :attr:`history` 0)."""

    history: ClassVar[int] = ProgressDetector.history

    def __init__(self, detector: ProgressDetector) -> None:
        super().__init__()
        self.detector = detector
        self._work = detector.workspace()

    def update(self, step: int, embedding: np.ndarray) -> float:
        """``s(step)`` of the embedding ``[E]`` of policy step ``step`` (the expected one)."""
        x = check_input(embedding, (self.detector.embedding_dim,), "an embedding", ProgressError)
        self._expect(step)
        score = self.detector._score(step, x, self._work)  # noqa: SLF001 - the one scoring function of both forms
        self._advance()
        return score
