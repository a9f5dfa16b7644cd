"""Calibrated thresholds ``gamma_t`` for the aggregated scores (Sec. 4.3, App. A.3).

All thresholds are fitted on the aggregated score curves ``eta_i(t)`` of the *successful*
calibration rollouts ``i = 1..M`` (curves may have different lengths). Kinds:

- ``"cp_constant"``: ``gamma = `` the empirical ``ceil((M+1)(1-delta))/M`` quantile of the
  per-rollout maxima ``max_t eta_i(t)`` (App. A.3, the CP-constant theorem: the inf-definition, i.e. the
  ``ceil((M+1)(1-delta))``-th smallest maximum). If that level exceeds 1 (``M`` too small for
  ``delta``) no finite threshold has the guarantee: ``+inf`` is returned and a warning logged.
- ``"cp_band"``: one-sided conformal band (App. A.3 after Diquigiovanni et al.). The rollouts are
  split (seeded) into ``I1`` and ``I2`` (default 50/50). ``mu(t)`` is the mean and ``s(t)`` the standard deviation
  over the ``I1`` rollouts running at ``t``; ``s(t)`` is floored at ``std_floor`` times its mean over
  the well-supported steps so that steps where all ``I1`` curves coincide (often ``t = 0``) cannot dominate. Neither
  depends on ``I2``. Band scores ``R_i = max_t (eta_i(t) - mu(t)) / s(t)`` for ``i in I2`` (upper
  sign), ``k`` = their conformal quantile at level ``ceil((M2+1)(1-delta))/M2``, and
  ``gamma_t = mu(t) + k s(t)``.
- ``"time_varying"``: the per-step empirical ``1-delta`` quantile (numpy's linear interpolation)
  over the rollouts still running at ``t``; no finite-sample guarantee (a quantile per step bounds the
  false-alarm rate of each step, not of a whole rollout, which alarms if any step does).
- ``"cp_scaled"``: the time-varying shape kept, with a rollout-level guarantee: ``q(t)`` is the per-step
  ``1-delta`` quantile of the ``I1`` curves (floored at ``std_floor`` times its mean over the
  well-supported steps, like the band's scale), ``R_i = max_t eta_i(t) / q(t)`` for ``i in I2``, ``k`` their
  conformal quantile and ``gamma_t = k q(t)``: the one-sided band of App. A.3 with ``mu = 0`` and
  ``s(t) = q(t)``, so Proposition 1 holds for it as for the CP band.
- ``"gaussian"``: ``gamma_t = mu(t) + z(1-delta) sigma(t)`` (App. A.3 remark), ``mu`` from ``I1``,
  ``sigma(t)`` the root-mean-square deviation of the ``I2`` curves from ``mu(t)``.

Where the split comes from: by default ``I1`` and ``I2`` are a seeded split of the given curves. A caller
that already holds curves of a disjoint set of rollouts passes them as ``shape_curves``: they are ``I1``
(the per-step shape: ``mu``, ``s``, ``q``) and every given curve is in ``I2`` (the conformal quantile).
:func:`fiper_ros.core.calibration.calibrate` does so with the rollouts the score model was fitted on,
so no rollout of the conformal set was seen by anything fitted (the premise of Proposition 1).

Band rule (``ThresholdSettings.band_rule``): the above is ``"paper"``. ``"reference"`` is the CP band of the
authors' code (the ``"reference"`` profile), with their float operations; it has no finite-sample guarantee:

- split: the longest curve (the first of equal longest ones) and the first ``floor((M-1)/2)`` of the other
  ``M-1`` curves *in the order given* are ``I1`` (longest first), the rest ``I2``; no seed, no ``band_split``.
  The authors' loader gives the calibration rollouts in sorted file-name order, so the curves must come in
  that order to match their split (the FIPER converter reads the files so, and calibration and evaluation
  keep the order of the successes). With ``shape_curves``, those are ``I1`` and every given curve is in
  ``I2``, as in the paper rule.
- ``mu(t)``: ``np.mean`` over the ``I1`` curves that reach ``t``, for ``t`` up to the longest ``I1`` curve
  ``T_1`` (no support rule).
- filter: with ``N1 = |I1|`` and ``q = 1 - delta``, every ``I1`` curve is kept if ``(N1 + 1) q > N1``; else
  the curves whose ``max_t |eta_i(t) - mu(t)|`` is at most ``np.quantile`` (linear) of those maxima. The
  filter makes the band depend on delta beyond ``k``.
- modulation: ``s(t) = max |eta_i(t) - mu(t)|`` over the kept curves that reach ``t``, ``1/t`` where none
  does, and ``1/T_1`` wherever that is below ``1e-7``.
- band scores over ``t < min(len(eta_i), T_1)`` with ``band_sign``; ``gamma_t = mu(t) + k s(t)`` for
  ``t < T_1``, the extension beyond (the authors' code: ``"mean"``).

Support rule: a per-step statistic at ``t`` is only computed where at least ``min_support``
rollouts of the set it is computed from reach ``t`` (default ``max(5, M // 5)``, capped at the set
size). Later steps, up to the longest calibration rollout, carry the last well-supported value
forward. Steps beyond the longest calibration rollout use the threshold's ``extension``: ``"last"``
(default), ``"mean"`` (the authors' code, through a config-key typo) or ``"max"`` of the values.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from statistics import NormalDist
from typing import Any

import numpy as np

from fiper_ros.core.errors import CoreError

LOG = logging.getLogger(__name__)

KINDS = ("cp_constant", "cp_band", "time_varying", "cp_scaled", "gaussian")
#: Kinds whose false-alarm rate on a whole new successful rollout is at most delta (Proposition 1).
GUARANTEED_KINDS = ("cp_constant", "cp_band", "cp_scaled")
EXTENSIONS = ("last", "mean", "max")
BAND_SIGNS = ("upper", "lower")
#: How ``cp_band`` splits and models its band: the paper's (seeded split, floored standard deviation) or the
#: authors' code's (see the module docstring).
BAND_RULES = ("paper", "reference")
#: The authors' modulation: a value below this is replaced by ``1 / T_1``.
_AUTHORS_SMALL_SCALE = 1e-7
# Guards ceil() against (M+1)(1-delta) landing a rounding error above an integer.
_CEIL_TOLERANCE = 1e-9


class ThresholdError(CoreError):
    """Thresholds cannot be fitted or read."""


@dataclass(frozen=True)
class ThresholdSettings:
    """How to fit a threshold.

    Attributes:
        kind: One of ``KINDS``.
        delta: Target false-alarm rate, in (0, 1).
        extension: Rule for steps beyond the longest calibration rollout, one of ``EXTENSIONS``.
        min_support: Rollouts a step needs for per-step statistics; ``None``: ``max(5, M // 5)``.
        band_split: Fraction of rollouts in ``I1`` for ``cp_band`` and ``gaussian``.
        band_sign: ``"upper"`` (paper) or ``"lower"`` (the authors' code) band score.
        conformal: Conformal quantile (paper); ``False`` uses ``np.quantile`` as the authors' code.
        std_floor: ``s(t) >= std_floor * mean_t s(t)`` for ``cp_band``.
        seed: Seed of the ``I1``/``I2`` split.
        band_rule: ``"paper"`` or ``"reference"`` (the authors' split, filter and modulation) for
            ``cp_band``; the reference rule ignores ``band_split``, ``std_floor``, ``seed`` and ``min_support``.
    """

    kind: str = "cp_band"
    delta: float = 0.05
    extension: str = "last"
    min_support: int | None = None
    band_split: float = 0.5
    band_sign: str = "upper"
    conformal: bool = True
    std_floor: float = 0.1
    seed: int = 0
    band_rule: str = "paper"

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ThresholdError(f"unknown threshold kind {self.kind!r}; expected one of {KINDS}")
        if not 0.0 < self.delta < 1.0:
            raise ThresholdError(f"delta must be in (0, 1), got {self.delta}")
        if self.extension not in EXTENSIONS:
            raise ThresholdError(f"unknown extension {self.extension!r}; expected one of {EXTENSIONS}")
        if self.band_sign not in BAND_SIGNS:
            raise ThresholdError(f"unknown band_sign {self.band_sign!r}; expected one of {BAND_SIGNS}")
        if self.band_rule not in BAND_RULES:
            raise ThresholdError(f"unknown band_rule {self.band_rule!r}; expected one of {BAND_RULES}")
        if not 0.0 < self.band_split < 1.0:
            raise ThresholdError(f"band_split must be in (0, 1), got {self.band_split}")
        if self.min_support is not None and self.min_support < 1:
            raise ThresholdError(f"min_support must be >= 1, got {self.min_support}")
        if self.std_floor < 0:
            raise ThresholdError(f"std_floor must be >= 0, got {self.std_floor}")


@dataclass(frozen=True, eq=False)
class Threshold:
    """A fitted threshold ``gamma_t`` over policy steps ``t = 0..len(values)-1`` and its extension."""

    kind: str
    delta: float
    values: np.ndarray
    extension: str = "last"
    params: dict[str, Any] = field(default_factory=dict)
    tail: float = field(init=False, repr=False)
    """``gamma_t`` for every ``t >= len(values)`` (the extension rule applied)."""

    def __post_init__(self) -> None:
        values = np.array(self.values, dtype=np.float64)
        if values.ndim != 1 or values.shape[0] == 0:
            raise ThresholdError(f"threshold values must be a non-empty 1-D array, got shape {values.shape}")
        if np.any(np.isnan(values)):
            raise ThresholdError("threshold values contain NaN")
        if self.extension not in EXTENSIONS:
            raise ThresholdError(f"unknown extension {self.extension!r}; expected one of {EXTENSIONS}")
        values.flags.writeable = False
        object.__setattr__(self, "values", values)
        tail = {"last": values[-1], "mean": np.mean(values), "max": np.max(values)}[self.extension]
        object.__setattr__(self, "tail", float(tail))

    def at(self, t: int) -> float:
        """``gamma_t`` at policy step ``t >= 0``."""
        if t < 0:
            raise IndexError(f"policy step must be >= 0, got {t}")
        return float(self.values[t]) if t < self.values.shape[0] else self.tail

    def over(self, length: int) -> np.ndarray:
        """``gamma_t`` for ``t = 0..length-1``."""
        out = np.full(length, self.tail)
        n = min(length, self.values.shape[0])
        out[:n] = self.values[:n]
        return out

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form for the calibration file."""
        return {
            "kind": self.kind,
            "delta": float(self.delta),
            "extension": self.extension,
            "values": [float(v) for v in self.values],
            "params": dict(self.params),
        }

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Threshold:
        """Inverse of :meth:`to_dict`."""
        try:
            return cls(data["kind"], float(data["delta"]), np.asarray(data["values"], dtype=np.float64),
                       data.get("extension", "last"), dict(data.get("params", {})))
        except KeyError as error:
            raise ThresholdError(f"threshold entry lacks {error}") from error


def conformal_quantile(scores: Sequence[float] | np.ndarray, delta: float) -> float:
    """The empirical ``ceil((M+1)(1-delta))/M`` quantile of ``M`` scores (App. A.3, inf-definition).

    Returns ``+inf`` (with a warning) when ``ceil((M+1)(1-delta)) > M``.
    """
    ordered = np.sort(np.asarray(scores, dtype=np.float64))
    m = ordered.shape[0]
    if m == 0:
        raise ThresholdError("conformal quantile of no scores")
    rank = math.ceil((m + 1) * (1.0 - delta) - _CEIL_TOLERANCE)
    if rank > m:
        LOG.warning("conformal level ceil((M+1)(1-delta))/M > 1 for M=%d, delta=%g: threshold is +inf", m, delta)
        return math.inf
    return float(ordered[rank - 1])


def minimum_conformal_set(delta: float) -> int:
    """The fewest scores whose conformal ``1-delta`` quantile is finite: the smallest ``M`` with
    ``ceil((M+1)(1-delta)) <= M`` (19 for delta = 0.05, 9 for 0.1).

    ``ceil((M+1)(1-delta)) <= M`` holds exactly when ``(M+1)(1-delta) <= M``, that is ``M >= (1-delta)/delta``;
    with the tolerance :func:`conformal_quantile` allows, so that both agree (a property test checks it).
    """
    if not 0.0 < delta < 1.0:
        raise ThresholdError(f"delta must be in (0, 1), got {delta}")
    return max(1, math.ceil((1.0 - delta) / delta - _CEIL_TOLERANCE))


def _quantile(scores: np.ndarray, delta: float, conformal: bool) -> float:
    return conformal_quantile(scores, delta) if conformal else float(np.quantile(scores, 1.0 - delta))


def _validated(curves: Sequence[np.ndarray]) -> list[np.ndarray]:
    if len(curves) == 0:
        raise ThresholdError("no calibration curves: thresholds need successful calibration rollouts")
    out = []
    for i, curve in enumerate(curves):
        array = np.asarray(curve, dtype=np.float64)
        if array.ndim != 1 or array.shape[0] == 0:
            raise ThresholdError(f"calibration curve {i} must be a non-empty 1-D array, got shape {array.shape}")
        if np.any(np.isnan(array)):
            raise ThresholdError(f"calibration curve {i} contains NaN")
        out.append(array)
    return out


def _padded(curves: list[np.ndarray], length: int) -> np.ndarray:
    """``[len(curves), length]`` matrix, NaN where a rollout has ended."""
    matrix = np.full((len(curves), length), np.nan)
    for i, curve in enumerate(curves):
        matrix[i, : curve.shape[0]] = curve
    return matrix


def _supported_length(matrix: np.ndarray, min_support: int | None) -> int:
    """Number of leading steps reached by at least ``min_support`` rollouts (at least 1)."""
    n = matrix.shape[0]
    need = min(max(5, n // 5) if min_support is None else min_support, n)
    counts = np.sum(~np.isnan(matrix), axis=0)
    return max(1, int(np.sum(counts >= need)))


def _carried(values: np.ndarray, supported: int, length: int) -> np.ndarray:
    """``values[:supported]`` extended to ``length`` with its last entry (the support rule)."""
    out = np.empty(length)
    out[:supported] = values[:supported]
    out[supported:] = values[supported - 1]
    return out


def _per_step(matrix: np.ndarray, min_support: int | None, statistic: str, q: float = 0.0) -> np.ndarray:
    supported = _supported_length(matrix, min_support)
    head = matrix[:, :supported]
    if statistic == "mean":
        values = np.nanmean(head, axis=0)
    elif statistic == "std":
        values = np.nanstd(head, axis=0)
    else:
        values = np.nanquantile(head, q, axis=0)
    return _carried(values, supported, matrix.shape[1])


def _split(m: int, settings: ThresholdSettings) -> tuple[np.ndarray, np.ndarray]:
    if m < 2:
        raise ThresholdError(f"{settings.kind} needs at least 2 calibration rollouts to split, got {m}")
    order = np.random.default_rng(settings.seed).permutation(m)
    m1 = min(max(round(settings.band_split * m), 1), m - 1)
    return order[:m1], order[m1:]


@dataclass(frozen=True)
class BandStatistics:
    """A one-sided CP band before its factor ``k`` (eqs. 12-13): ``gamma_t = mu + k s``; independent of delta
    with the paper band rule (the reference rule's filter depends on it, :class:`AuthorsBand`)."""

    mu: np.ndarray
    """``mu(t)`` from ``I1``."""
    scale: np.ndarray
    """The modulation ``s(t)`` from ``I1`` (floored; the reference rule's fill-ins)."""
    band_scores: np.ndarray
    """``R_i = max_t sign (eta_i(t) - mu(t)) / s(t)`` for ``i in I2``."""
    m1: int
    m2: int
    floor: float

    def values(self, k: float) -> np.ndarray:
        """``mu + k s``, or ``+inf`` everywhere when ``k`` is not finite."""
        return self.mu + k * self.scale if math.isfinite(k) else np.full(self.mu.shape[0], math.inf)


def _floored(spread: np.ndarray, supported: int, s: ThresholdSettings, reference: np.ndarray) -> tuple[np.ndarray, float]:
    """``spread`` floored at ``std_floor`` times its mean over the well-supported steps (a tiny positive
    floor where that is 0), and the floor."""
    floor = s.std_floor * float(np.mean(spread[:supported]))
    if floor <= 0.0:
        floor = 1e-12 * max(1.0, float(np.max(np.abs(reference))))
    return np.maximum(spread, floor), floor


def _shape_and_conformal(curves: list[np.ndarray], s: ThresholdSettings,
                         shape_curves: list[np.ndarray] | None) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """``I1`` (the shape) and ``I2`` (the conformal set): ``shape_curves`` and ``curves`` when given, else a
    seeded split of ``curves``."""
    if shape_curves is not None:
        return shape_curves, curves
    first, second = _split(len(curves), s)
    return [curves[i] for i in first], [curves[i] for i in second]


def _running_means(curves: list[np.ndarray]) -> np.ndarray:
    """``np.mean`` of the values at ``t`` of the curves that reach ``t``, in the curves' order, for every ``t`` up
    to the longest curve: bit for bit the per-step 1-D ``np.mean`` (numpy's pairwise sum along a contiguous
    row), computed once per run of steps that the same curves reach."""
    lengths = sorted({curve.shape[0] for curve in curves})
    means = np.empty(lengths[-1])
    start = 0
    for end in lengths:
        block = np.stack([curve[start:end] for curve in curves if curve.shape[0] >= end], axis=1)
        means[start:end] = np.mean(block, axis=1)
        start = end
    return means


@dataclass(frozen=True, eq=False)
class AuthorsBand:
    """The delta-independent part of the authors' CP band (the ``"reference"`` band rule, module docstring):
    ``I1`` (longest first), ``I2``, ``mu`` and each ``I1`` curve's largest deviation from ``mu``."""

    set1: list[np.ndarray]
    set2: list[np.ndarray]
    mu: np.ndarray
    deviations: np.ndarray
    """``max_t |eta_i(t) - mu(t)|`` per ``I1`` curve, in ``set1``'s order."""

    @classmethod
    def of(cls, curves: list[np.ndarray], shape_curves: list[np.ndarray] | None = None) -> AuthorsBand:
        """The authors' split of ``curves`` in their order (``I1``: the first longest curve, then the first
        ``floor((M-1)/2)`` of the others), or ``shape_curves`` as ``I1`` and every curve in ``I2``."""
        if shape_curves is not None:
            set1, set2 = list(shape_curves), list(curves)
        else:
            if len(curves) < 2:
                raise ThresholdError(f"cp_band needs at least 2 calibration rollouts to split, got {len(curves)}")
            longest = max(range(len(curves)), key=lambda i: curves[i].shape[0])  # the first of equal ones
            others = [curve for i, curve in enumerate(curves) if i != longest]
            half = len(others) // 2
            set1, set2 = [curves[longest], *others[:half]], others[half:]
        mu = _running_means(set1)
        deviations = np.array([np.max(np.abs(c - mu[: c.shape[0]])) for c in set1])
        return cls(set1, set2, mu, deviations)

    def kept(self, delta: float) -> tuple[int, ...]:
        """The authors' filter: the ``I1`` curves (indices) whose deviation is at most the ``1 - delta`` quantile
        of the deviations, or all of them when ``(N1 + 1)(1 - delta) > N1``."""
        q, n1 = 1.0 - delta, len(self.set1)
        if (n1 + 1) * q > n1:
            return tuple(range(n1))
        return tuple(int(i) for i in np.flatnonzero(self.deviations <= np.quantile(self.deviations, q)))

    def statistics(self, kept: tuple[int, ...], band_sign: str) -> BandStatistics:
        """``mu``, the modulation over the ``kept`` curves (:meth:`kept`) and the band scores of ``I2`` with
        ``band_sign``; ``floor`` is the fill-in ``1 / T_1``."""
        length = self.mu.shape[0]
        padded = _padded([self.set1[i] for i in kept], length)
        spread = np.fmax.reduce(np.abs(padded - self.mu), axis=0)  # NaN where no kept curve reaches t
        unreached = np.isnan(spread)  # never t = 0: every kept curve reaches it
        spread[unreached] = 1.0 / np.flatnonzero(unreached)
        fill = 1.0 / length
        spread[spread < _AUTHORS_SMALL_SCALE] = fill
        sign = 1.0 if band_sign == "upper" else -1.0
        ends = [min(c.shape[0], length) for c in self.set2]
        scores = np.array([np.max(sign * (c[:n] - self.mu[:n]) / spread[:n]) for c, n in zip(self.set2, ends)])
        return BandStatistics(self.mu, spread, scores, len(self.set1), len(self.set2), fill)


def band_statistics(curves: list[np.ndarray], length: int, s: ThresholdSettings,
                    shape_curves: list[np.ndarray] | None = None) -> BandStatistics:
    """Split, ``mu``, ``s`` and the band scores of the CP band; with the paper rule only ``k`` depends on
    delta. The reference rule's (:class:`AuthorsBand`) are as long as the longest ``I1`` curve, not ``length``."""
    if s.band_rule == "reference":
        band = AuthorsBand.of(curves, shape_curves)
        return band.statistics(band.kept(s.delta), s.band_sign)
    set1, set2 = _shape_and_conformal(curves, s, shape_curves)
    padded = _padded(set1, length)
    mu = _per_step(padded, s.min_support, "mean")
    scale, floor = _floored(_per_step(padded, s.min_support, "std"), _supported_length(padded, s.min_support), s, mu)
    sign = 1.0 if s.band_sign == "upper" else -1.0
    band_scores = np.array([np.max(sign * (c - mu[: c.shape[0]]) / scale[: c.shape[0]]) for c in set2])
    return BandStatistics(mu, scale, band_scores, len(set1), len(set2), floor)


def _conformal_factor(stats: BandStatistics, s: ThresholdSettings, floor_key: str
                      ) -> tuple[np.ndarray, dict[str, Any]]:
    """``mu + k scale`` with ``k`` the conformal quantile of the band scores (App. A.3), and its parameters."""
    k = _quantile(stats.band_scores, s.delta, s.conformal)
    return stats.values(k), {"k": float(k), "m1": stats.m1, "m2": stats.m2, floor_key: stats.floor}


def _cp_band(curves: list[np.ndarray], length: int, s: ThresholdSettings,
             shape_curves: list[np.ndarray] | None) -> tuple[np.ndarray, dict[str, Any]]:
    return _conformal_factor(band_statistics(curves, length, s, shape_curves), s, "s_floor")


def scaled_statistics(curves: list[np.ndarray], length: int, s: ThresholdSettings,
                      shape_curves: list[np.ndarray] | None = None) -> BandStatistics:
    """``q(t)`` (as ``scale``, ``mu = 0``) and the scores ``max_t eta_i(t) / q(t)`` of ``cp_scaled``."""
    set1, set2 = _shape_and_conformal(curves, s, shape_curves)
    padded = _padded(set1, length)
    shape = _per_step(padded, s.min_support, "quantile", 1.0 - s.delta)
    scale, floor = _floored(shape, _supported_length(padded, s.min_support), s, shape)
    scores = np.array([np.max(c / scale[: c.shape[0]]) for c in set2])
    return BandStatistics(np.zeros(length), scale, scores, len(set1), len(set2), floor)


def _cp_scaled(curves: list[np.ndarray], length: int, s: ThresholdSettings,
               shape_curves: list[np.ndarray] | None) -> tuple[np.ndarray, dict[str, Any]]:
    return _conformal_factor(scaled_statistics(curves, length, s, shape_curves), s, "q_floor")


def _gaussian(curves: list[np.ndarray], length: int, s: ThresholdSettings,
              shape_curves: list[np.ndarray] | None) -> tuple[np.ndarray, dict[str, Any]]:
    set1, set2 = _shape_and_conformal(curves, s, shape_curves)
    mu = _per_step(_padded(set1, length), s.min_support, "mean")
    padded2 = _padded(set2, length)
    supported = _supported_length(padded2, s.min_support)
    sigma = np.sqrt(np.nanmean((padded2[:, :supported] - mu[:supported]) ** 2, axis=0))
    z = NormalDist().inv_cdf(1.0 - s.delta)
    return mu + z * _carried(sigma, supported, length), {"z": z, "m1": len(set1), "m2": len(set2)}


def fit_threshold(curves: Sequence[np.ndarray], settings: ThresholdSettings | None = None,
                  shape_curves: Sequence[np.ndarray] | None = None) -> Threshold:
    """Fit ``gamma_t`` on the aggregated score curves of successful calibration rollouts.

    ``shape_curves``: curves of other successful rollouts, disjoint from ``curves``, for the per-step
    shape of ``cp_band``, ``cp_scaled`` and ``gaussian`` (see the module docstring); the other kinds use
    ``curves`` only. With ``band_rule="reference"`` the order of ``curves`` decides the ``cp_band`` split: the
    authors' order is that of their calibration files' sorted names.
    """
    s = settings or ThresholdSettings()
    checked = _validated(curves)
    shape = None if shape_curves is None else _validated(shape_curves)
    length = max(curve.shape[0] for curve in checked + (shape or []))
    params: dict[str, Any] = {"m": len(checked)}
    if s.kind == "cp_constant":
        gamma = _quantile(np.array([curve.max() for curve in checked]), s.delta, s.conformal)
        values = np.full(length, gamma)
    elif s.kind == "time_varying":
        values = _per_step(_padded(checked, length), s.min_support, "quantile", 1.0 - s.delta)
    else:
        fit = {"cp_band": _cp_band, "cp_scaled": _cp_scaled, "gaussian": _gaussian}[s.kind]
        values, extra = fit(checked, length, s, shape)
        params.update(extra)
    return Threshold(s.kind, s.delta, values, s.extension, params)
