"""Runtime failure prediction with a calibration: streaming and vectorised (Sec. 4).

The ROS nodes, bag replay and offline evaluation all use this module. The streaming monitors take
one policy step at a time; :func:`predict_rollout` processes a whole recorded rollout. Both compute
the per-step scores with :mod:`fiper_ros.core.scores`, aggregate in float64 in the same order
(:mod:`fiper_ros.core.window`) and compare with the same thresholds, so they agree bit for bit.

Streaming monitors expect policy steps ``0, 1, 2, ...`` in order after every :meth:`reset`; a gap or
repeat raises :class:`MonitorError` because the windowed score would be wrong (eq. 2), unless the
caller declares the lost steps with ``skip_to`` (then results are flagged ``complete=False`` while a
missing step is inside the window). A step whose input was rejected, or whose score is not finite
(:class:`~fiper_ros.core.scores.NonFiniteScore`), is declared with ``missing``: it enters the window as
0 and its result carries only the lower bound. Every decision is :func:`fiper_ros.core.fusion.exceeds`.

With an observation-only calibration (RND-OE alone, :mod:`fiper_ros.core.detectors`) there is no ACE
part: :class:`ActionMonitor` refuses it, :func:`predict_rollout` judges with RND-OE's exceedance alone (the
ACE results are NaN / False), and no action batches are needed. The streaming fusion with its latch is the
fusion node's (:class:`fiper_ros.runtime.alarm.AlarmFuser`, over the monitors' published scores).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from fiper_ros.core.calibration import Calibration, CalibrationError
from fiper_ros.core.fusion import exceeds, first_alarm, fuse_declared
from fiper_ros.core.kinematics import ForwardKinematics
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scores import act_score, act_scores, obs_score, obs_scores, rollout_positions
from fiper_ros.core.thresholds import Threshold
from fiper_ros.core.window import WindowAccumulator, aggregate


class MonitorError(ValueError):
    """Out-of-order policy steps or malformed inputs."""


@dataclass(frozen=True)
class StepScore:
    """One predictor's result at one policy step."""

    step: int
    score: float
    """Per-step score ``s_RND`` or ``s_ACE``."""
    windowed: float
    """Aggregated score ``eta`` (eq. 2 or 5)."""
    threshold: float
    """``gamma_t``."""
    exceeded: bool
    """``eta > gamma_t`` (eq. 3 or the action analogue)."""
    complete: bool = True
    """False while the window holds a step marked missing by :meth:`skip_to`; ``windowed`` is then a
    lower bound of eq. (2)/(6) (per-step scores are >= 0), so ``exceeded`` is certain only when True."""


class _StreamingPredictor:
    """Window, threshold and step bookkeeping shared by the two streaming predictors."""

    def __init__(self, threshold: Threshold, window: int, mode: str) -> None:
        self._threshold = threshold
        self._window = WindowAccumulator(window, mode)
        # How many later steps a missing step stays inside the aggregation window.
        self._span = {"window": self._window.w, "max": self._window.w, "single": 1}.get(mode, np.inf)
        self._next = 0
        self._complete_from: float = 0

    @property
    def next_step(self) -> int:
        """The policy step :meth:`update` expects next."""
        return self._next

    def reset(self) -> None:
        """Start a new rollout."""
        self._window.reset()
        self._next = 0
        self._complete_from = 0

    def skip_to(self, step: int) -> None:
        """Mark the steps from :attr:`next_step` up to ``step - 1`` as missing (input lost or rejected).

        Each enters the window as a score of 0, so the next :meth:`update` may be ``step``; results
        whose window still holds a missing step are flagged ``complete=False``. The cost is O(w) however
        large the gap: only the last ``w`` steps are inside a window.
        """
        if step <= self._next:
            return
        self._window.skip(step - self._next)
        self._complete_from = step - 1 + self._span
        self._next = step

    def missing(self, step: int) -> StepScore:
        """Declare policy step ``step`` (the expected one) missing and return its lower-bound result.

        The per-step score is NaN, ``windowed`` the window's sum with this step as 0 (a lower bound, as
        scores are >= 0), ``complete`` False; ``exceeded`` is therefore certain when True.
        """
        self._expect(step)
        eta = self._window.push(0.0)
        self._next += 1
        self._complete_from = step + self._span
        gamma = self._threshold.at(step)
        return StepScore(step, math.nan, eta, gamma, bool(exceeds(eta, gamma)), False)

    def _expect(self, step: int) -> None:
        if step != self._next:
            raise MonitorError(f"expected policy step {self._next}, got {step} (call reset() for a new rollout)")

    def _step(self, step: int, score: float) -> StepScore:
        self._expect(step)
        eta = self._window.push(score)
        self._next += 1
        gamma = self._threshold.at(step)
        return StepScore(step, score, eta, gamma, bool(exceeds(eta, gamma)), step >= self._complete_from)


class ObservationMonitor(_StreamingPredictor):
    """Streaming RND-OE predictor ``F_O`` (eqs. 1-3)."""

    def __init__(self, calibration: Calibration) -> None:
        settings = calibration.settings
        super().__init__(calibration.threshold_obs, settings.window_obs, settings.aggregation)
        self._calibration = calibration

    def update(self, step: int, embedding: np.ndarray) -> StepScore:
        """Score the observation embedding ``[E]`` of policy step ``step``."""
        embedding = np.asarray(embedding)
        self._expect(step)
        self._calibration.check_compatible(embedding_dim=embedding.shape[-1])
        return self._step(step, obs_score(self._calibration.rnd, embedding, self._calibration.profile))


class ActionMonitor(_StreamingPredictor):
    """Streaming ACE predictor ``F_A`` (eqs. 4-6)."""

    def __init__(self, calibration: Calibration, fk: ForwardKinematics | None = None) -> None:
        settings = calibration.settings
        if calibration.threshold_act is None:
            raise CalibrationError(f"the calibration is observation-only (detectors "
                                   f"{','.join(calibration.detectors)}): it has no ACE threshold to score action "
                                   "batches with")
        super().__init__(calibration.threshold_act, settings.window_act, settings.aggregation)
        self._calibration = calibration
        self._projection = calibration.projection(fk)
        self._cell = calibration.cell

    def update(self, step: int, actions: np.ndarray, q_current: np.ndarray | None = None) -> StepScore:
        """Score the sampled action chunks ``[B, H, D]`` of policy step ``step``.

        ``q_current`` (the measured joint position) is required for joint-velocity actions.
        """
        actions = np.asarray(actions)
        self._expect(step)
        if actions.ndim != 3:
            raise MonitorError(f"actions must be [B, H, D], got shape {actions.shape}")
        self._calibration.check_compatible(action_dim=actions.shape[2], horizon=actions.shape[1])
        positions = self._projection(actions, q_current)
        return self._step(step, act_score(positions, self._cell, self._calibration.profile))


@dataclass(frozen=True)
class RolloutPrediction:
    """Vectorised FIPER output over one rollout (arrays of length ``T``; the ``act_*`` ones NaN / False for an
    observation-only calibration, whose ``alarms`` are RND-OE's exceedances)."""

    obs_scores: np.ndarray
    act_scores: np.ndarray
    obs_windowed: np.ndarray
    act_windowed: np.ndarray
    obs_thresholds: np.ndarray
    act_thresholds: np.ndarray
    obs_exceeded: np.ndarray
    act_exceeded: np.ndarray
    alarms: np.ndarray
    first_alarm_step: int | None


def predict_rollout(
    rollout: Rollout, calibration: Calibration, fk: ForwardKinematics | None = None
) -> RolloutPrediction:
    """Run FIPER over a recorded rollout (with the detectors the calibration declares)."""
    settings, profile = calibration.settings, calibration.profile
    calibration.check_compatible(embedding_dim=rollout.embeddings.shape[1])
    s_obs = obs_scores(calibration.rnd, rollout.embeddings, profile)
    eta_obs = aggregate(s_obs, settings.aggregation, settings.window_obs)
    gamma_obs = calibration.threshold_obs.over(rollout.length)
    obs_exceeded = np.asarray(exceeds(eta_obs, gamma_obs), dtype=bool)
    if calibration.threshold_act is None:  # observation-only: RND-OE alone
        s_act, eta_act, gamma_act = (np.full(rollout.length, np.nan) for _ in range(3))
        act_exceeded = np.zeros(rollout.length, dtype=bool)
        alarms = np.asarray(fuse_declared([obs_exceeded], settings.combine), dtype=bool)
    else:
        if rollout.actions is None:
            raise MonitorError(f"rollout {rollout.rollout_id!r} has no action batches: the calibration declares ACE "
                               "(an observation-only calibration scores it with RND-OE alone)")
        calibration.check_compatible(action_dim=rollout.actions.shape[3], horizon=rollout.actions.shape[2])
        s_act = act_scores(rollout_positions(rollout, calibration.projection(fk)), calibration.cell, profile)
        eta_act = aggregate(s_act, settings.aggregation, settings.window_act)
        gamma_act = calibration.threshold_act.over(rollout.length)
        act_exceeded = np.asarray(exceeds(eta_act, gamma_act), dtype=bool)
        alarms = np.asarray(fuse_declared([obs_exceeded, act_exceeded], settings.combine), dtype=bool)
    return RolloutPrediction(s_obs, s_act, eta_obs, eta_act, gamma_obs, gamma_act, obs_exceeded, act_exceeded, alarms,
                             first_alarm(alarms))
