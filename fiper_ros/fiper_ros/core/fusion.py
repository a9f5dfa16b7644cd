"""Combining the detectors' decisions, eq. (7) and App. A.4, generalised to N detectors.

Every combination is a vote: a step alarms when at least ``votes`` of the N declared detectors exceed their
thresholds (the comparisons are strict). The paper's ``F = 1(eta_O > gamma_O,t AND eta_A > gamma_A,t)`` needs
every vote; its OR one. A *joint* combination (``max``, ``kth:K``; :mod:`fiper_ros.core.combination`) votes the
same way, but its per-detector thresholds share one conformal factor, so its promise is ``delta`` however many
detectors vote (the OR's is ``N x delta``): ``max`` needs one vote, ``kth:K`` K. One detector alone is its own
decision, whatever the combine. A rollout is flagged as failing at its first alarm (:func:`first_alarm`); the
latch that keeps that state for the rest of the rollout is the fusion node's
(:class:`fiper_ros.runtime.alarm.AlarmFuser`) and, over a recorded rollout, the offline oracle's running OR.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.errors import ChoiceError


@dataclass(frozen=True)
class Combine:
    """How the declared detectors' decisions make the alarm: ``and``, ``or``, ``max`` or ``kth:K``; any other mode or
    count is a :class:`~fiper_ros.core.errors.ChoiceError` in one line."""

    mode: CombineMode
    k: int = 0
    """The votes ``kth`` needs (0 for the other modes)."""

    def __post_init__(self) -> None:
        if self.mode not in tuple(CombineMode):
            raise ChoiceError(f"unknown combine {self.mode!r}; expected one of "
                              f"{', '.join(mode.written for mode in CombineMode)}")
        object.__setattr__(self, "mode", CombineMode(self.mode))
        if (self.mode is CombineMode.KTH) != (self.k >= 1):
            raise ChoiceError("kth:K needs K >= 1" if self.mode is CombineMode.KTH else f"{self.mode} takes no K")

    @classmethod
    def parse(cls, text: str) -> Combine:
        """``"and"``, ``"or"``, ``"max"`` or ``"kth:K"``; :class:`~fiper_ros.core.errors.ChoiceError` in one line
        otherwise."""
        mode, _, count = str(text).partition(":")
        if mode == CombineMode.KTH:
            if not count.isdigit() or int(count) < 1:
                raise ChoiceError(f"combine {text!r}: kth:K needs an integer K >= 1 (e.g. kth:2)")
            return cls(CombineMode.KTH, int(count))
        if count:
            raise ChoiceError(f"combine {text!r}: only kth takes a count (kth:K)")
        return cls(mode)  # type: ignore[arg-type]  # checked and converted by __post_init__

    @property
    def joint(self) -> bool:
        """Whether the detectors share one conformal factor (``max``, ``kth``)."""
        return self.mode.joint

    def votes(self, detectors: int) -> int:
        """How many of ``detectors`` must exceed for an alarm (one detector alone: 1, whatever the mode);
        :class:`~fiper_ros.core.errors.ChoiceError` for ``kth:K`` over fewer than K detectors (a combine the
        declared detectors do not offer). ``detectors`` < 1 is the caller's error (``ValueError``)."""
        if detectors < 1:
            raise ValueError(f"at least one detector's decision is needed, got {detectors}")
        if self.mode is CombineMode.KTH and self.k > detectors:
            raise ChoiceError(f"combine kth:{self.k} needs at least {self.k} detectors, got {detectors}")
        return {CombineMode.AND: detectors, CombineMode.OR: 1, CombineMode.MAX: 1, CombineMode.KTH: self.k}[self.mode]

    def promised_multiple(self, detectors: int) -> int:
        """How many deltas Proposition 1 promises for ``detectors`` thresholds combined so, each set at delta: ``N``
        for an OR of ``N`` (the union bound), 1 for AND, a joint combine (one conformal factor) or one detector."""
        return detectors if self.mode is CombineMode.OR else 1

    def __str__(self) -> str:
        return f"kth:{self.k}" if self.mode is CombineMode.KTH else self.mode.value


def exceeds(eta: np.ndarray | float, gamma: np.ndarray | float) -> np.ndarray | bool:
    """``eta > gamma`` (eqs. 3 and 6's decision functions ``F_O``, ``F_A``), in float64 for Python floats (the
    fusion node's one step, without numpy's per-call cost) and element-wise for arrays."""
    if type(eta) is float and type(gamma) is float:
        return eta > gamma
    return np.greater(eta, gamma)


def fuse(exceeded_obs: np.ndarray | bool, exceeded_act: np.ndarray | bool, combine: str = CombineMode.AND) -> np.ndarray | bool:
    """``F_O AND F_A`` (eq. 7) or ``F_O OR F_A``, element-wise."""
    return fuse_declared([exceeded_obs, exceeded_act], combine)


def fuse_votes(exceeded: Sequence[np.ndarray | bool], votes: int) -> np.ndarray | bool:
    """Element-wise: at least ``votes`` of the decisions are True."""
    if all(type(e) is bool for e in exceeded):  # one step's decisions (the fusion node), without numpy's cost
        return sum(exceeded) >= votes
    stacked = np.asarray(exceeded, dtype=bool)
    return np.count_nonzero(stacked, axis=0) >= votes if stacked.ndim > 1 else bool(np.count_nonzero(stacked) >= votes)


def fuse_declared(exceeded: Sequence[np.ndarray | bool], combine: str | Combine = CombineMode.AND) -> np.ndarray | bool:
    """The alarm over the declared detectors' decisions: at least :meth:`Combine.votes` of them exceed
    (two with ``and``: eq. 7; one alone: its own decision)."""
    rule = combine if isinstance(combine, Combine) else Combine.parse(combine)
    votes = rule.votes(len(exceeded))
    fused = fuse_votes(exceeded, votes)
    return np.asarray(fused, dtype=bool) if np.ndim(exceeded[0]) else fused


def first_alarm(alarms: np.ndarray) -> int | None:
    """Index of the first ``True`` in a per-step alarm array, or ``None``."""
    alarms = np.asarray(alarms, dtype=bool)
    return int(np.argmax(alarms)) if alarms.any() else None


def alarms_over_rollout(
    eta_obs: np.ndarray, gamma_obs: np.ndarray, eta_act: np.ndarray, gamma_act: np.ndarray, combine: str = CombineMode.AND
) -> tuple[np.ndarray, int | None]:
    """Vectorised eq. (7) over a rollout: per-step alarms ``[T]`` and the first alarm step."""
    alarms = np.asarray(fuse(exceeds(eta_obs, gamma_obs), exceeds(eta_act, gamma_act), combine), dtype=bool)
    return alarms, first_alarm(alarms)
