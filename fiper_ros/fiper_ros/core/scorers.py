"""Fitted detectors behind one interface: what a calibration fits, stores, loads and scores with.

A :class:`Scorer` is one detector fitted on successful rollouts (or fitted on nothing: the elapsed time, a
logged signal). It gives the per-step score ``s_d(t) >= 0`` of a whole rollout (:meth:`Scorer.scores`, the
offline evaluation and the replay oracle) and one policy step at a time (:meth:`Scorer.stream`, the nodes), the
same numbers bit for bit; it says what of it goes into ``calibration.yaml`` (:meth:`Scorer.entry`) and which
files beside it (:meth:`Scorer.save`, checked by :meth:`Scorer.digest`).

What each detector reads at a step (:data:`fiper_ros.core.detectors.READS`) is the value its stream's
``update`` takes: an embedding ``[E]`` (RND-OE eq. 1, logpZO, PCA-kmeans, progress), an action batch ``[B, H, D]``
with the measured joint position for joint-velocity actions (ACE eq. 4, consistency), a logged value (a signal:
its magnitude), or nothing (the elapsed time: 1 per step). :func:`fit_scorer` and :func:`load_scorer` are the
registry: one entry per detector a calibration may declare.
"""

from __future__ import annotations

import hashlib
import json
from abc import ABC, abstractmethod
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from fiper_ros.core.ace import action_ranges, cell_size
from fiper_ros.core.consistency import ActionConsistency, ConsistencySettings
from fiper_ros.core.detectors import (ACE, CONSISTENCY, ELAPSED, LOGPZO, PCA_KMEANS, PROGRESS, RND_OE, SIGNAL_PREFIX,
                                      check_declared, info)
from fiper_ros.core.errors import CoreError
from fiper_ros.core.kinematics import ActionProjection, ForwardKinematics
from fiper_ros.core.logpzo import LogpZO, LogpZOConfig
from fiper_ros.core.pca_kmeans import PCAKMeans, PCAKMeansConfig
from fiper_ros.core.profiles import Profile
from fiper_ros.core.progress import ProgressDetector, ProgressSettings
from fiper_ros.core.rnd_oe import RNDOE, ProgressCallback, RNDConfig
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scores import act_score, act_scores, finite, obs_score, obs_scores, rollout_positions
from fiper_ros.core.step_stream import StepStream


@dataclass(frozen=True)
class DetectorOptions:
    """Every detector's own settings (the calibration's; each detector reads its part)."""

    rnd: RNDConfig
    alpha: float
    action_dims: tuple[int, int] | None = None
    control_dt: float | None = None
    progress: ProgressSettings = ProgressSettings()
    consistency: ConsistencySettings = ConsistencySettings()
    logpzo: LogpZOConfig = LogpZOConfig()
    pca_kmeans: PCAKMeansConfig = PCAKMeansConfig()


@dataclass(frozen=True)
class FitContext:
    """What a fit needs besides the successes: the seed, the profile, the options, the robot model (ACE on
    joint-space actions), the action layout, rollouts whose actions also set ACE's ranges (the reference profile's
    failed calibration rollouts) and a training progress callback (RND-OE)."""

    seed: int
    profile: Profile
    options: DetectorOptions
    action_space: str = "ee_position"
    fk: ForwardKinematics | None = None
    extra_ranges: Sequence[Rollout] = ()
    progress: ProgressCallback | None = None


class ScoreStream(StepStream):
    """A scorer's streaming form: :meth:`update` scores policy steps ``0, 1, 2, ...`` of one rollout."""

    def __init__(self, score: Callable[[int, Any], float]) -> None:
        super().__init__()
        self._score = score

    def update(self, step: int, value: Any) -> float:  # what the detector reads (module docstring)
        """``s(step)`` of the value the detector reads at policy step ``step`` (the expected one)."""
        self._expect(step)
        score = self._score(step, value)
        self._advance()
        return score


class Scorer(ABC):
    """One fitted detector (module docstring)."""

    name: str
    #: Earlier policy steps a score reads (0: the step's own input only).
    history: ClassVar[int] = 0

    @abstractmethod
    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        """``s(t)`` ``[T]`` (float64) of a whole rollout; :class:`~fiper_ros.core.scores.NonFiniteScore` if a step's
        score is not finite."""

    @abstractmethod
    def stream(self, fk: ForwardKinematics | None = None) -> StepStream:
        """The streaming form, at step 0 (``fk``: the robot model of ACE on joint-space actions)."""

    def entry(self) -> dict[str, Any]:
        """What ``calibration.yaml`` says of the fitted detector (plain data; the files beside it hold the rest)."""
        return {}

    def save(self, directory: Path) -> None:
        """Write the detector's model files into ``directory`` (none for a detector that fits no model)."""

    def digest(self) -> str:
        """SHA-256 over the fitted state (what a calibration's content hash covers)."""
        return hashlib.sha256(json.dumps(self.entry(), sort_keys=True).encode()).hexdigest()


class ScorerInputError(CoreError):
    """A rollout lacks what a detector reads (action batches, a logged signal)."""


class _Stateless(Scorer):
    """A scorer whose step score reads only that step: the streaming form is the per-step function."""

    @abstractmethod
    def score_one(self, step: int, value: Any) -> float:  # what the detector reads
        """The score of one step."""

    def stream(self, fk: ForwardKinematics | None = None) -> ScoreStream:
        return ScoreStream(self.score_one)


class RndOeScorer(_Stateless):
    """RND-OE (eq. 1, App. A.2): ``s_RND = ||f(O^e) - g(O^e)||`` with the profile's epsilon."""

    name = RND_OE

    def __init__(self, rnd: RNDOE, profile: Profile) -> None:
        self.rnd = rnd
        self.profile = profile

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        return obs_scores(self.rnd, rollout.embeddings, self.profile)

    def score_one(self, step: int, value: np.ndarray) -> float:
        return obs_score(self.rnd, value, self.profile)

    def save(self, directory: Path) -> None:
        self.rnd.save(directory)

    def digest(self) -> str:
        return self.rnd.digest()


def _actions(rollout: Rollout, label: str) -> np.ndarray:
    if rollout.actions is None:
        raise ScorerInputError(f"rollout {rollout.rollout_id!r} has no action batches, which {label} reads")
    return rollout.actions


class AceScorer(Scorer):
    """ACE (eq. 4, App. A.1) on end-effector positions, cell ``alpha R_d`` with the profile's binning; a step's
    value is its batch ``[B, H, D]`` and the measured joint position (``None`` but for joint velocities)."""

    name = ACE

    def __init__(self, ranges: np.ndarray, options: DetectorOptions, action_space: str, profile: Profile) -> None:
        self.ranges = np.asarray(ranges, dtype=np.float64)
        self.options = options
        self.action_space = action_space
        self.profile = profile
        self.cell = cell_size(self.ranges, options.alpha, profile.ace_binning)

    def projection(self, fk: ForwardKinematics | None) -> ActionProjection:
        """The action-to-position mapping (``fk`` for joint-space actions)."""
        return ActionProjection(self.action_space, self.options.action_dims, fk, self.options.control_dt)

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        _actions(rollout, "ACE")
        return act_scores(rollout_positions(rollout, self.projection(fk)), self.cell, self.profile)

    def stream(self, fk: ForwardKinematics | None = None) -> ScoreStream:
        projection = self.projection(fk)
        return ScoreStream(lambda step, value: act_score(projection(*value), self.cell, self.profile))

    def entry(self) -> dict[str, Any]:
        return {"alpha": float(self.options.alpha), "ranges": [float(r) for r in self.ranges]}


class _ModelFiles:
    """A scorer around a model of :mod:`fiper_ros.core.detector_model` (its files, digest and the profile's
    epsilon on its scores)."""

    name: str
    model: LogpZO | PCAKMeans | ProgressDetector | ActionConsistency
    profile: Profile

    def _epsilon(self, scores: np.ndarray) -> np.ndarray:
        return finite(np.asarray(scores, dtype=np.float64) + self.profile.score_epsilon,
                      f"{info(self.name).label} score")

    def save(self, directory: Path) -> None:
        self.model.save(directory)

    def digest(self) -> str:
        return self.model.digest()


class EmbeddingScorer(_ModelFiles, _Stateless):
    """logpZO or PCA-kmeans: a score of the step's embedding alone."""

    def __init__(self, name: str, model: LogpZO | PCAKMeans, profile: Profile) -> None:
        self.name = name
        self.model = model
        self.profile = profile

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        return self._epsilon(self.model.scores(rollout))

    def score_one(self, step: int, value: np.ndarray) -> float:
        return float(self._epsilon(np.float64(self.model.score_one(value))))


class _Wrapped(StepStream):
    """A detector's own streaming form (its step order and what it keeps of earlier steps), its scores passed
    through ``finish`` (the profile's epsilon); ``read`` picks the detector's input of a step's value."""

    def __init__(self, inner: Any, read: Callable[[Any], Any], finish: Callable[[np.ndarray], np.ndarray]) -> None:
        super().__init__()
        self.inner = inner
        self.history = inner.history
        self._read = read
        self._finish = finish

    @property
    def next_step(self) -> int:
        return self.inner.next_step

    def reset(self) -> None:
        self.inner.reset()

    def skip_to(self, step: int) -> None:
        self.inner.skip_to(step)

    def update(self, step: int, value: Any) -> float:
        """``s(step)`` of the detector's input at ``step`` (the expected one)."""
        return float(self._finish(np.float64(self.inner.update(step, self._read(value)))))


class ProgressScorer(_ModelFiles, Scorer):
    """Progress: the elapsed share of a typical success ahead of the progress estimated from the embedding."""

    name = PROGRESS

    def __init__(self, model: ProgressDetector, profile: Profile) -> None:
        self.model = model
        self.profile = profile

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        return self._epsilon(self.model.scores(rollout.embeddings))

    def stream(self, fk: ForwardKinematics | None = None) -> StepStream:
        return _Wrapped(self.model.stream(), lambda value: value, self._epsilon)


class ConsistencyScorer(_ModelFiles, Scorer):
    """Single-sample action consistency: the disagreement of consecutive executed chunks (reads one earlier step;
    a step's value is ACE's: the batch and a joint position, which it does not use)."""

    name = CONSISTENCY
    history: ClassVar[int] = 1

    def __init__(self, model: ActionConsistency, profile: Profile) -> None:
        self.model = model
        self.profile = profile

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        return self._epsilon(self.model.scores(_actions(rollout, "action consistency")))

    def stream(self, fk: ForwardKinematics | None = None) -> StepStream:
        return _Wrapped(self.model.stream(), lambda value: value[0], self._epsilon)


class ElapsedScorer(_Stateless):
    """The elapsed time: 1 per policy step (its cumulative sum is the steps elapsed); fits nothing."""

    name = ELAPSED

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        return np.ones(rollout.length)

    def score_one(self, step: int, value: Any) -> float:  # nothing is read
        return 1.0


class SignalScorer(_Stateless):
    """A logged per-step signal: its magnitude (a score is >= 0); fits nothing."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.signal = name.removeprefix(SIGNAL_PREFIX)

    def scores(self, rollout: Rollout, fk: ForwardKinematics | None = None) -> np.ndarray:
        if self.signal not in rollout.signals:
            raise ScorerInputError(f"rollout {rollout.rollout_id!r} has no signal {self.signal!r} (it has "
                                   f"{', '.join(sorted(rollout.signals)) or 'none'})")
        return finite(np.abs(np.asarray(rollout.signals[self.signal], dtype=np.float64)), f"signal {self.signal}")

    def score_one(self, step: int, value: float) -> float:
        return float(finite(np.float64(abs(float(value))), f"signal {self.signal}"))


def fit_scorer(name: str, successes: Sequence[Rollout], context: FitContext) -> Scorer:
    """Fit detector ``name`` on ``successes`` (every one a success of one layout)."""
    check_declared(name)
    options, profile = context.options, context.profile
    if name == RND_OE:
        from fiper_ros.core.rnd_train import fit_rnd  # noqa: PLC0415 - torch only where RND-OE is trained

        embeddings = np.concatenate([r.embeddings for r in successes])
        return RndOeScorer(fit_rnd(embeddings, options.rnd, context.seed, context.progress), profile)
    if name == ACE:
        projection = ActionProjection(context.action_space, options.action_dims, context.fk, options.control_dt)
        ranges = action_ranges(rollout_positions(r, projection) for r in [*successes, *context.extra_ranges])
        return AceScorer(ranges, options, context.action_space, profile)
    if name == LOGPZO:
        return EmbeddingScorer(name, LogpZO(options.logpzo).fit(successes, context.seed), profile)
    if name == PCA_KMEANS:
        return EmbeddingScorer(name, PCAKMeans(options.pca_kmeans).fit(successes, context.seed), profile)
    if name == PROGRESS:
        return ProgressScorer(ProgressDetector.fit(successes, options.progress, context.seed), profile)
    if name == CONSISTENCY:
        return ConsistencyScorer(ActionConsistency.fit(successes, options.consistency), profile)
    if name == ELAPSED:
        return ElapsedScorer()
    return SignalScorer(name)


def load_scorer(name: str, directory: Path, entry: dict[str, Any], options: DetectorOptions, action_space: str,
                profile: Profile) -> Scorer:
    """The detector ``name`` a calibration stored in ``directory`` (its model files) and ``entry`` (its part of
    ``calibration.yaml``); the model classes' own errors name a missing or damaged file."""
    check_declared(name)
    if name == RND_OE:
        return RndOeScorer(RNDOE.load(directory), profile)
    if name == ACE:
        return AceScorer(np.asarray(entry["ranges"], dtype=np.float64), options, action_space, profile)
    if name == LOGPZO:
        return EmbeddingScorer(name, LogpZO.load(directory), profile)
    if name == PCA_KMEANS:
        return EmbeddingScorer(name, PCAKMeans.load(directory), profile)
    if name == PROGRESS:
        return ProgressScorer(ProgressDetector.load(directory), profile)
    if name == CONSISTENCY:
        return ConsistencyScorer(ActionConsistency.load(directory), profile)
    if name == ELAPSED:
        return ElapsedScorer()
    return SignalScorer(name)
