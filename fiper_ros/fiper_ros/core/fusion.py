"""Combining the observation- and action-based predictors, eq. (7) and App. A.4.

``F = 1(eta_O > gamma_O,t AND eta_A > gamma_A,t)`` (default) or the OR variant; the comparisons are
strict. A calibration that declares one detector alone (observation-only, :mod:`fiper_ros.core.detectors`)
has no second decision to combine: its alarm is that detector's exceedance and the AND/OR does not
apply (:func:`fuse_declared`). A rollout is flagged as failing at its first alarm (:func:`first_alarm`); the
latch that keeps that state for the rest of the rollout is the fusion node's (:class:`fiper_ros.runtime.alarm.AlarmFuser`)
and, over a recorded rollout, the offline oracle's running OR of the alarms.
"""

from __future__ import annotations

from collections.abc import Sequence

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


def fuse_declared(exceeded: Sequence[np.ndarray | bool], combine: str = "and") -> np.ndarray | bool:
    """FIPER's decision over the declared detectors' decisions, in :data:`~fiper_ros.core.detectors.DETECTORS`
    order: two are fused by :func:`fuse`; one alone is its own decision (``combine`` does not apply)."""
    _check_combine(combine)
    if len(exceeded) == 2:
        return fuse(exceeded[0], exceeded[1], combine)
    if len(exceeded) == 1:
        return np.asarray(exceeded[0], dtype=bool)
    raise ValueError(f"one or two detectors' decisions expected, got {len(exceeded)}")


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
