"""Runtime failure prediction with a calibration: streaming and vectorised (Sec. 4).

The ROS nodes, bag replay and offline evaluation all use this module. :class:`DetectorMonitor` takes one policy
step at a time for one declared detector; :func:`predict_rollout` processes a whole recorded rollout for every
declared detector and votes. Both compute the per-step scores with the calibration's fitted scorers
(:mod:`fiper_ros.core.scorers`: the streaming and the whole-rollout form of a detector agree bit for bit),
aggregate in float64 in the same order (:mod:`fiper_ros.core.window`) and compare with the same thresholds, so
they agree bit for bit.

A streaming monitor expects policy steps ``0, 1, 2, ...`` in order after every :meth:`DetectorMonitor.reset`; a
gap or repeat raises :class:`MonitorError` because the windowed score would be wrong (eq. 2), unless the caller
declares the lost steps with ``skip_to`` (then results are flagged ``complete=False`` while a missing step is
inside the window, or read by the score: a detector that reads earlier steps, :attr:`Scorer.history`). A step
whose input was rejected, or whose score is not finite (:class:`~fiper_ros.core.scores.NonFiniteScore`), is
declared with ``missing``: it enters the window as 0 and its result carries only the lower bound. Every decision
is :func:`fiper_ros.core.fusion.exceeds`; the votes of the detectors' decisions with the latch are the fusion
node's (:class:`fiper_ros.runtime.alarm.AlarmFuser`) and, over a rollout, :func:`predict_rollout`'s.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from fiper_ros.core.calibration import Calibration, CalibrationMismatch
from fiper_ros.core.detectors import info
from fiper_ros.core.errors import CoreError
from fiper_ros.core.fusion import exceeds, first_alarm, fuse_votes
from fiper_ros.core.kinematics import ForwardKinematics
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scores import step_joint_position
from fiper_ros.core.step_stream import StepOrderError
from fiper_ros.core.window import WindowAccumulator, aggregate


class MonitorError(CoreError):
    """Out-of-order policy steps or malformed inputs."""


@dataclass(frozen=True)
class StepScore:
    """One detector's result at one policy step."""

    step: int
    score: float
    """Per-step score ``s_d(t)`` (``s_RND``, ``s_ACE``, ...)."""
    windowed: float
    """Aggregated score ``eta_d(t)`` (eq. 2 or 5)."""
    threshold: float
    """``gamma_d,t``."""
    exceeded: bool
    """``eta > gamma_t`` (eq. 3 or its analogue)."""
    complete: bool = True
    """False while the window holds a step marked missing (or the score reads one); ``windowed`` is then a lower
    bound (per-step scores are >= 0), so ``exceeded`` is certain only when True."""


class DetectorMonitor:
    """Streaming predictor of one declared detector for one task: its score (eqs. 1, 4, ...), window (eqs. 2, 5),
    threshold and exceedance (eqs. 3, 6)."""

    def __init__(self, calibration: Calibration, detector: str, task: str = "",
                 fk: ForwardKinematics | None = None) -> None:
        settings = calibration.settings
        self.detector = detector
        self._reads = info(detector).reads
        self._layout = calibration.layout
        self._threshold = calibration.threshold(detector, task)
        self._scorer = calibration.scorer(detector, task)
        self._stream = self._scorer.stream(fk)
        mode = settings.aggregation_of(detector)
        self._window = WindowAccumulator(settings.window_of(detector), mode)
        # How many later steps a missing step stays inside the window or the score's inputs.
        self._span = {"window": self._window.w, "max": self._window.w, "single": 1}.get(mode, math.inf) \
            + self._scorer.history
        self._next = 0
        self._complete_from: float = 0

    def _check(self, value: Any) -> None:
        """The input's shape against the calibration's layout: an embedding ``[E]``, a batch ``[B, H, D]``."""
        layout = self._layout
        if self._reads == "embedding" and np.shape(value) != (layout.embedding_dim,):
            raise CalibrationMismatch("embedding_dim", layout.embedding_dim, np.shape(value)[-1:] or np.shape(value))
        if self._reads == "actions":
            shape = np.shape(value[0])
            if len(shape) != 3:
                raise MonitorError(f"actions must be [B, H, D], got shape {shape}")
            if layout.has_actions and shape[1:] != (layout.horizon, layout.action_dim):
                raise CalibrationMismatch("horizon, action_dim", (layout.horizon, layout.action_dim), shape[1:])

    @property
    def window(self) -> int:
        """The detector's window ``w`` (1 for the cumulative sum and the single step)."""
        return self._window.w

    @property
    def next_step(self) -> int:
        """The policy step :meth:`update` expects next."""
        return self._next

    def reset(self) -> None:
        """Start a new rollout."""
        self._window.reset()
        self._stream.reset()
        self._next = 0
        self._complete_from = 0

    def skip_to(self, step: int) -> None:
        """Mark the steps from :attr:`next_step` up to ``step - 1`` as missing (input lost or rejected).

        Each enters the window as a score of 0, so the next :meth:`update` may be ``step``; results whose window
        still holds a missing step (or whose score reads one) are flagged ``complete=False``. The cost is O(w)
        however large the gap: only the last ``w`` steps are inside a window.
        """
        if step <= self._next:
            return
        self._window.skip(step - self._next)
        self._stream.skip_to(step)
        self._complete_from = step - 1 + self._span
        self._next = step

    def missing(self, step: int) -> StepScore:
        """Declare policy step ``step`` (the expected one) missing and return its lower-bound result.

        The per-step score is NaN, ``windowed`` the window's sum with this step as 0 (a lower bound, as scores are
        >= 0), ``complete`` False; ``exceeded`` is therefore certain when True.
        """
        self._expect(step)
        eta = self._window.push(0.0)
        self._next += 1
        self._stream.skip_to(self._next)
        self._complete_from = step + self._span
        gamma = self._threshold.at(step)
        return StepScore(step, math.nan, eta, gamma, bool(exceeds(eta, gamma)), False)

    def _expect(self, step: int) -> None:
        if step != self._next:
            raise MonitorError(f"expected policy step {self._next}, got {step} (call reset() for a new rollout)")

    def update(self, step: int, value: Any) -> StepScore:  # what the detector reads (scorers)
        """Score the input of policy step ``step``: an embedding ``[E]``, an action batch ``[B, H, D]`` with the
        measured joint position (``(actions, q)``), a logged value, or nothing (the elapsed time)."""
        self._expect(step)
        self._check(value)
        try:
            score = self._stream.update(step, value)
        except StepOrderError as error:
            raise MonitorError(str(error)) from error
        eta = self._window.push(score)
        self._next += 1
        gamma = self._threshold.at(step)
        return StepScore(step, score, eta, gamma, bool(exceeds(eta, gamma)), step >= self._complete_from)


@dataclass(frozen=True)
class DetectorTrace:
    """One detector over one rollout (arrays of length ``T``)."""

    scores: np.ndarray
    """``s_d(t)``."""
    windowed: np.ndarray
    """``eta_d(t)``."""
    thresholds: np.ndarray
    """``gamma_d,t``."""
    exceeded: np.ndarray
    """``eta_d(t) > gamma_d,t``."""


@dataclass(frozen=True)
class RolloutPrediction:
    """Every declared detector over one rollout, and the votes: per-step alarms and the first alarm step."""

    detectors: dict[str, DetectorTrace]
    alarms: np.ndarray
    first_alarm_step: int | None


def rollout_value(rollout: Rollout, detector: str, step: int) -> Any:  # what the detector reads
    """What ``detector`` reads at ``step`` of a recorded rollout (as a node receives it)."""
    reads = info(detector).reads
    if reads == "embedding":
        return rollout.embeddings[step]
    if reads == "actions":
        return rollout.actions[step], step_joint_position(rollout, step)
    if reads == "signal":
        return float(rollout.signals[detector.removeprefix("signal_")][step])
    return None


def predict_rollout(rollout: Rollout, calibration: Calibration, fk: ForwardKinematics | None = None
                    ) -> RolloutPrediction:
    """Run the calibration's detectors over a recorded rollout (its task's part) and vote (eq. 7, generalised)."""
    settings = calibration.settings
    actions = rollout.actions.shape if rollout.actions is not None else None
    if calibration.layout.has_actions and actions is None:
        raise MonitorError(f"rollout {rollout.rollout_id!r} has no action batches, which the calibration's detectors "
                           "read")
    calibration.check_compatible(embedding_dim=rollout.embeddings.shape[1], task=rollout.task,
                                 **({"action_dim": actions[3], "horizon": actions[2]}
                                    if calibration.layout.has_actions else {}))
    traces = {}
    for detector in settings.detectors:
        scores = calibration.scorer(detector, rollout.task).scores(rollout, fk)
        eta = aggregate(scores, settings.aggregation_of(detector), settings.window_of(detector))
        gamma = calibration.threshold(detector, rollout.task).over(rollout.length)
        traces[detector] = DetectorTrace(scores, eta, gamma, np.asarray(exceeds(eta, gamma), dtype=bool))
    alarms = np.asarray(fuse_votes([t.exceeded for t in traces.values()], settings.votes), dtype=bool)
    return RolloutPrediction(traces, alarms, first_alarm(alarms))
