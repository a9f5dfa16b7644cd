"""The combine modes: how the declared detectors vote (eq. 7 and its generalisations, :mod:`fiper_ros.core.fusion`).

Without numpy: the launcher and the calibration file reader name a calibration's combine without loading the method.
"""
from __future__ import annotations

from enum import StrEnum

__all__ = ["COMBINES", "CombineMode"]


class CombineMode(StrEnum):
    """How the declared detectors vote (its value is the name a calibration, a flag and ``FailureAlarm.combine``
    write): ``and`` every one (eq. 7), ``or`` one, each with a threshold calibrated at delta on its own; ``max``
    one and ``kth`` (written ``kth:K``) K, over thresholds that share one conformal factor (*joint*:
    :mod:`fiper_ros.core.combination`)."""

    AND = "and"
    OR = "or"
    MAX = "max"
    KTH = "kth"

    @property
    def joint(self) -> bool:
        """Whether the detectors share one conformal factor (``max``, ``kth``)."""
        return self in (CombineMode.MAX, CombineMode.KTH)

    @property
    def written(self) -> str:
        """The mode as a combine is written: ``kth:K`` for :attr:`KTH`, else the value."""
        return f"{self.value}:K" if self is CombineMode.KTH else self.value


#: Combines with a threshold per detector, each calibrated at delta on its own (AND: delta, OR: N x delta).
COMBINES = tuple(mode.value for mode in CombineMode if not mode.joint)
