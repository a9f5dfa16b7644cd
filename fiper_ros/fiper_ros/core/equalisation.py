"""Equalising the detectors' tails before a joint combination (:mod:`fiper_ros.core.combination`).

A joint ``max`` compares every detector's normalised score ``z_d(t)`` against one factor ``k``. When one
detector's ``z`` reaches far higher values on successes than the others' (a heavy tail), the conformal ``k`` is
set by it and the others never exceed. An *equaliser* is a strictly increasing, continuous map ``T_d`` fitted per
detector on the rollout maxima ``max_t z_d(t)`` of the fit part's successes (never the conformal ones); the joint
combination then combines ``T_d(z_d(t))`` instead of ``z_d(t)``:

- ``"quantile"``: ``T(z) = z / c`` with ``c`` the ``level`` quantile (numpy's linear interpolation) of the
  maxima, so every detector's success maxima sit at about 1; ``c`` must be positive.
- ``"tail"``: ``T(z) = -log S(z)``, ``S`` the empirical survival function of the maxima ``x_(1) <= .. <= x_(n)``
  with the plotting positions ``S(x_(i)) = 1 - i / (n + 1)`` (a tie takes its largest ``i``), interpolated
  linearly in ``-log S`` between the distinct maxima, and beyond them an exponential tail: ``-log S`` continues
  linearly with the slope of the secant from the median maximum to the largest, on both sides. The combined
  ``max`` of ``T_d`` is then the smallest tail probability (p-value) over the detectors.

Both are piecewise linear with linear ends (:class:`Equaliser`), finite everywhere and strictly increasing, so
``T_d(z) > k`` exactly when ``z > T_d^{-1}(k)``: the joint threshold of detector ``d`` stays
``offset_d(t) + T_d^{-1}(k) scale_d(t)``, a per-detector threshold that the nodes compare as before. ``T_d``
depends on the fit part only, so Proposition 1 holds for the equalised combination as for the plain one.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from fiper_ros.core.thresholds import ThresholdError

#: How a joint combination equalises its detectors: not at all, by a quantile of their maxima, by their tails.
EQUALISATIONS = ("none", "quantile", "tail")
#: The quantile of the fit part's maxima that ``"quantile"`` maps to 1, unless configured.
DEFAULT_LEVEL = 0.9


#: Rollout maxima closer than this, relative to the largest magnitude (at least 1), are one value to
#: :func:`tail_equaliser`.
TIE_RESOLUTION = 1e-9


@dataclass(frozen=True, eq=False)
class Equaliser:
    """A strictly increasing piecewise-linear map: ``levels`` at ``knots`` (both strictly increasing), linear
    interpolation between them, slope ``below`` before the first knot and ``above`` after the last."""

    kind: str
    knots: np.ndarray
    levels: np.ndarray
    below: float
    above: float

    def __post_init__(self) -> None:
        knots, levels = (np.array(v, dtype=np.float64) for v in (self.knots, self.levels))
        if knots.ndim != 1 or knots.shape != levels.shape or knots.shape[0] < 2:
            raise ThresholdError(f"an equaliser needs at least 2 knots and as many levels, got {knots.shape} and "
                                 f"{levels.shape}")
        finite = np.all(np.isfinite(knots)) and np.all(np.isfinite(levels))
        if not (finite and np.all(np.diff(knots) > 0) and np.all(np.diff(levels) > 0)):
            raise ThresholdError("an equaliser's knots and levels must be finite and strictly increasing")
        if not (math.isfinite(self.below) and math.isfinite(self.above) and self.below > 0 and self.above > 0):
            raise ThresholdError(f"an equaliser's end slopes must be finite and positive, got {self.below} and "
                                 f"{self.above}")
        for name, value in (("knots", knots), ("levels", levels)):
            value.flags.writeable = False
            object.__setattr__(self, name, value)

    def __call__(self, z: np.ndarray) -> np.ndarray:
        """``T(z)`` element-wise (NaN stays NaN)."""
        z = np.asarray(z, dtype=np.float64)
        out = np.interp(z, self.knots, self.levels)
        low, high = z < self.knots[0], z > self.knots[-1]
        out[low] = self.levels[0] + self.below * (z[low] - self.knots[0])
        out[high] = self.levels[-1] + self.above * (z[high] - self.knots[-1])
        return out

    def inverse(self, k: float) -> float:
        """``T^{-1}(k)``: the normalised score that maps to ``k`` (``+inf`` for ``k = +inf``)."""
        if not math.isfinite(k):
            return k
        if k < self.levels[0]:
            return float(self.knots[0] + (k - self.levels[0]) / self.below)
        if k > self.levels[-1]:
            return float(self.knots[-1] + (k - self.levels[-1]) / self.above)
        return float(np.interp(k, self.levels, self.knots))

    def to_dict(self) -> dict[str, Any]:
        """Plain data for the calibration file."""
        return {"kind": self.kind, "knots": [float(v) for v in self.knots],
                "levels": [float(v) for v in self.levels], "below": float(self.below), "above": float(self.above)}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Equaliser:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(str(data["kind"]), np.asarray(data["knots"], dtype=np.float64),
                       np.asarray(data["levels"], dtype=np.float64), float(data["below"]), float(data["above"]))
        except KeyError as error:
            raise ThresholdError(f"equaliser entry lacks {error}") from error


def check_equalisation(kind: str, level: float) -> None:
    """:class:`ThresholdError` for an unknown equalisation or a quantile level outside (0, 1)."""
    if kind not in EQUALISATIONS:
        raise ThresholdError(f"unknown equalisation {kind!r}; expected one of {', '.join(EQUALISATIONS)}")
    if not 0.0 < level < 1.0:
        raise ThresholdError(f"the equalisation level must be in (0, 1), got {level}")


def quantile_equaliser(maxima: np.ndarray, level: float = DEFAULT_LEVEL) -> Equaliser:
    """``T(z) = z / c``, ``c`` the ``level`` quantile of ``maxima`` (module docstring)."""
    check_equalisation("quantile", level)
    c = float(np.quantile(_checked(maxima), level))
    if not c > 0.0:
        raise ThresholdError(f"quantile equalisation needs a positive {level:g} quantile of the fit part's maxima, "
                             f"got {c:.6g} (equalise tail instead)")
    return Equaliser("quantile", np.array([0.0, c]), np.array([0.0, 1.0]), 1.0 / c, 1.0 / c)


def tail_equaliser(maxima: np.ndarray) -> Equaliser:
    """``T(z) = -log S(z)``, the interpolated empirical survival function of ``maxima`` with exponential ends
    (module docstring). Maxima no more than :data:`TIE_RESOLUTION` apart (relative to the largest magnitude, at
    least 1) are one value: a gap near the float resolution would make a slope overflow."""
    checked = np.sort(_checked(maxima))
    n = checked.shape[0]
    resolution = TIE_RESOLUTION * max(1.0, float(np.max(np.abs(checked))))
    last = np.append(np.diff(checked) > resolution, True)  # the largest of each group of tied maxima
    knots = checked[last]
    if knots.shape[0] < 2:
        raise ThresholdError(f"tail equalisation needs at least 2 distinct maxima in the fit part, got "
                             f"{knots.shape[0]} (of {n})" + ("" if np.ptp(checked) == 0 else
                                                           f"; maxima {resolution:.3g} apart or less count as one"))
    ranks = np.flatnonzero(last) + 1.0  # the largest i of each distinct maximum
    levels = np.log((n + 1.0) / (n + 1.0 - ranks))
    median = min(int(np.searchsorted(ranks, (n + 1) / 2.0)), knots.shape[0] - 2)
    slope = float((levels[-1] - levels[median]) / (knots[-1] - knots[median]))
    return Equaliser("tail", knots, levels, slope, slope)


def fit_equaliser(kind: str, maxima: np.ndarray, level: float = DEFAULT_LEVEL) -> Equaliser:
    """The equaliser ``kind`` (``"quantile"`` or ``"tail"``) from the fit part's rollout maxima."""
    check_equalisation(kind, level)
    if kind == "none":
        raise ThresholdError("equalisation 'none' has no equaliser")
    return quantile_equaliser(maxima, level) if kind == "quantile" else tail_equaliser(maxima)


def _checked(maxima: np.ndarray) -> np.ndarray:
    values = np.asarray(maxima, dtype=np.float64).ravel()
    if values.shape[0] == 0:
        raise ThresholdError("an equaliser needs the maxima of at least one fit-part rollout")
    if not np.all(np.isfinite(values)):
        raise ThresholdError("an equaliser's maxima must be finite")
    return values
