"""Combining the observation- and action-based predictors, eq. (7) and App. A.4.

``F = 1(eta_O > gamma_O,t AND eta_A > gamma_A,t)`` (default) or the OR variant; the comparisons are
strict. A rollout is flagged as failing at its first alarm; :class:`FusionLatch` keeps that state
for the rest of the rollout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

COMBINES = ("and", "or")


def _check_combine(combine: str) -> str:
    if combine not in COMBINES:
        raise ValueError(f"unknown combine {combine!r}; expected one of {COMBINES}")
    return combine


def exceeds(eta: np.ndarray | float, gamma: np.ndarray | float) -> np.ndarray | bool:
    """``eta > gamma`` (eqs. 3 and 6's decision functions ``F_O``, ``F_A``)."""
    return np.greater(eta, gamma)


def fuse(exceeded_obs: np.ndarray | bool, exceeded_act: np.ndarray | bool, combine: str = "and") -> np.ndarray | bool:
    """``F_O AND F_A`` (eq. 7) or ``F_O OR F_A``, element-wise."""
    if _check_combine(combine) == "and":
        return np.logical_and(exceeded_obs, exceeded_act)
    return np.logical_or(exceeded_obs, exceeded_act)


def first_alarm(alarms: np.ndarray) -> int | None:
    """Index of the first ``True`` in a per-step alarm array, or ``None``."""
    alarms = np.asarray(alarms, dtype=bool)
    return int(np.argmax(alarms)) if alarms.any() else None


def alarms_over_rollout(
    eta_obs: np.ndarray, gamma_obs: np.ndarray, eta_act: np.ndarray, gamma_act: np.ndarray, combine: str = "and"
) -> tuple[np.ndarray, int | None]:
    """Vectorised eq. (7) over a rollout: per-step alarms ``[T]`` and the first alarm step."""
    alarms = np.asarray(fuse(exceeds(eta_obs, gamma_obs), exceeds(eta_act, gamma_act), combine), dtype=bool)
    return alarms, first_alarm(alarms)


@dataclass(frozen=True)
class FusionState:
    """Output of one :meth:`FusionLatch.update`."""

    alarm: bool
    """Eq. (7) at this step."""
    latched: bool
    """Whether any step so far raised an alarm."""
    first_alarm_step: int | None
    """Policy step of the first alarm, if any."""


class FusionLatch:
    """Streaming eq. (7): one call per policy step, latches the first alarm until :meth:`reset`."""

    def __init__(self, combine: str = "and") -> None:
        self.combine = _check_combine(combine)
        self.reset()

    def reset(self) -> None:
        """Start a new rollout."""
        self._step = 0
        self._first: int | None = None

    def update(self, exceeded_obs: bool, exceeded_act: bool) -> FusionState:
        """Fuse this step's two decisions ``F_O``, ``F_A``."""
        if self.combine == "and":
            alarm = bool(exceeded_obs) and bool(exceeded_act)
        else:
            alarm = bool(exceeded_obs) or bool(exceeded_act)
        if alarm and self._first is None:
            self._first = self._step
        self._step += 1
        return FusionState(alarm, self._first is not None, self._first)
