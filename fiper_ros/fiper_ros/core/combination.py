"""One conformal threshold over a combination of detectors (Sec. 4.3 and App. A.3-A.4, generalised to N).

FIPER fuses two detectors with AND or OR, each against its own threshold (eq. 7). AND alarms only when the
later detector does; OR keeps Proposition 1 only at ``N x delta`` (the union bound), so each threshold needs
``delta / N`` and N times the successes. A *joint* combination instead normalises every detector's windowed
curve by its per-step shape and sets ONE conformal factor over the combined statistic:

1. Per detector ``d`` a shape from the shape curves ``I1`` (the fit part's curves, never the conformal ones):
   ``"cp_band"``: ``z_d(t) = (eta_d(t) - mu_d(t)) / s_d(t)`` with the CP band's mean and floored standard
   deviation; ``"cp_scaled"``: ``z_d(t) = eta_d(t) / q_d(t)`` with CP scaled's floored per-step
   ``1 - delta`` quantile (:mod:`fiper_ros.core.thresholds`: the same statistics, support rule and floor);
   ``"cp_constant"``: ``z_d(t) = (eta_d(t) - m_d) / s_d``, one offset and scale for every step: the mean and the
   (floored) standard deviation of the shape curves' rollout maxima ``max_t eta_d(t)``, the statistic of CP
   constant thresholds (eq. 6). No per-step division: early steps, where the successes barely vary, are not
   magnified into the combination.
2. The combined statistic ``c(t)`` = the ``votes``-th largest of ``z_1(t) .. z_N(t)``: ``votes = 1`` is the
   maximum (alarms as early as the earliest detector), ``votes = K`` needs K detectors to agree.
3. The conformal score of a rollout is ``R = max_t c(t)``; ``k`` is the conformal quantile of the conformal
   rollouts' scores at ``delta`` (App. A.3's ``ceil((M+1)(1-delta))``-th smallest).
4. Detector ``d``'s threshold is ``gamma_d(t) = mu_d(t) + k s_d(t)`` (band), ``k q_d(t)`` (scaled) or the
   constant ``m_d + k s_d``, and a step alarms when at least ``votes`` detectors exceed theirs: ``c(t) > k``
   exactly when that holds.

Guarantee (Proposition 1 at ``delta``, not ``N x delta``): the shapes depend on the shape curves only, so the
scores ``R`` of the conformal rollouts and of a new successful rollout are exchangeable; a new success alarms at
some step exactly when its ``R`` exceeds ``k``, which has probability at most ``delta``. With one detector the
combination is that detector's CP band (CP scaled, CP constant) threshold, value for value (CP constant: up to
rounding, ``m + ((gamma - m) / s) s``).

Equalised (``equalise``, :mod:`fiper_ros.core.equalisation`): before step 2 each detector's ``z_d`` is mapped by its
equaliser ``T_d``, fitted on its fit-part maxima ``max_t z_d(t)`` of the shape curves, each normalised by the shape of
the other folds' shape curves (:func:`fold_maxima`: out of fold, as a conformal rollout is normalised by a shape it
did not fit); ``c(t)`` is the ``votes``-th largest ``T_d(z_d(t))`` and detector ``d``'s threshold is
``mu_d(t) + T_d^{-1}(k) s_d(t)`` (or ``T_d^{-1}(k) q_d(t)``). ``T_d`` is strictly increasing, so the vote over these
thresholds is still exactly ``c(t) > k``, and ``T_d`` depends on the shape curves only: the guarantee stands. Pooled,
each detector has one equaliser over every group's maxima.

Pooled over groups (tasks of a many-task policy): each group has its own shapes, the conformal scores of all
groups are pooled into one ``k``. The promise then holds for a new success drawn like the conformal rollouts
(the groups in their proportions), not for each group: a group's own rate may be above ``delta``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fiper_ros.core.equalisation import DEFAULT_LEVEL, Equaliser, check_equalisation, fit_equaliser
from fiper_ros.core.thresholds import (
    Threshold,
    ThresholdError,
    ThresholdSettings,
    _floored,
    _padded,
    _per_step,
    _quantile,
    _supported_length,
    _validated,
)

#: Folds of a group's shape curves in which :func:`fold_maxima` normalises each curve out of fold (fewer curves:
#: one fold each).
EQUALISER_FOLDS = 5

#: Normalisations a joint combination accepts: one per guaranteed threshold kind (module docstring, step 1).
SHAPE_KINDS = ("cp_band", "cp_scaled", "cp_constant")
#: The shapes that do not depend on delta (fitted once for every delta of a sweep).
DELTA_FREE_SHAPES = ("cp_band", "cp_constant")
#: The shapes that centre the fit part's rollout maxima on 0 (the constant shape subtracts their mean).
CENTRED_SHAPES = ("cp_constant",)


def equalisable(equalise: str, kind: str) -> bool:
    """Whether ``equalise`` applies to detectors normalised by ``kind``: quantile equalisation divides by a positive
    quantile of the fit part's maxima, which a centred shape does not give (tail equalisation applies to any)."""
    return not (equalise == "quantile" and kind in CENTRED_SHAPES)


@dataclass(frozen=True)
class Shape:
    """One detector's per-step shape in one group: ``z(t) = (eta(t) - offset(t)) / scale(t)``."""

    kind: str
    offset: np.ndarray
    """``mu(t)`` (band), 0 (scaled) or ``m`` at every step (constant)."""
    scale: np.ndarray
    """``s(t)`` (band), ``q(t)`` (scaled) or ``s`` at every step (constant), floored, > 0."""
    floor: float

    def normalised(self, curve: np.ndarray) -> np.ndarray:
        """``z(t)`` of a curve no longer than the shape (the core's band-score formula)."""
        n = curve.shape[0]
        return (curve - self.offset[:n]) / self.scale[:n]

    def values(self, k: float) -> np.ndarray:
        """``gamma(t) = offset(t) + k scale(t)``, ``+inf`` everywhere for an infinite ``k``."""
        return self.offset + k * self.scale if np.isfinite(k) else np.full(self.offset.shape[0], np.inf)


def fit_shape(shape_curves: Sequence[np.ndarray], length: int, kind: str, settings: ThresholdSettings) -> Shape:
    """The shape of ``kind`` from ``shape_curves`` over ``length`` steps, with the support rule and floor of
    :func:`fiper_ros.core.thresholds.band_statistics` (band) and ``scaled_statistics`` (scaled); constant: the
    maxima's mean and standard deviation (a tiny positive floor where all maxima are equal, as the band's)."""
    if kind not in SHAPE_KINDS:
        raise ThresholdError(f"a joint combination normalises with one of {', '.join(SHAPE_KINDS)}, not {kind!r}")
    if kind == "cp_constant":
        peaks = np.array([float(np.max(curve)) for curve in _validated(shape_curves)])
        mean = float(np.mean(peaks))
        spread, floor = _floored(np.array([np.std(peaks)]), 1, settings, np.array([mean]))
        return Shape(kind, np.full(length, mean), np.full(length, spread[0]), floor)
    padded = _padded(_validated(shape_curves), length)
    supported = _supported_length(padded, settings.min_support)
    if kind == "cp_band":
        mu = _per_step(padded, settings.min_support, "mean")
        scale, floor = _floored(_per_step(padded, settings.min_support, "std"), supported, settings, mu)
        return Shape(kind, mu, scale, floor)
    q = _per_step(padded, settings.min_support, "quantile", 1.0 - settings.delta)
    scale, floor = _floored(q, supported, settings, q)
    return Shape(kind, np.zeros(length), scale, floor)


def fold_maxima(shape_curves: Sequence[np.ndarray], length: int, kind: str, settings: ThresholdSettings
                ) -> np.ndarray:
    """``max_t z_i(t)`` of every shape curve ``i``, normalised by the shape (:func:`fit_shape`) of the shape curves
    of the other folds (curve ``i`` in fold ``i mod K``, ``K = min(EQUALISER_FOLDS, count)``): what an equaliser is
    fitted on. Needs at least 2 curves."""
    curves = _validated(shape_curves)
    count = len(curves)
    if count < 2:
        raise ThresholdError(f"equalising needs at least 2 shape curves per group, got {count}")
    folds = min(EQUALISER_FOLDS, count)
    out = np.empty(count)
    for fold in range(folds):
        shape = fit_shape([c for i, c in enumerate(curves) if i % folds != fold], length, kind, settings)
        for i in range(fold, count, folds):
            out[i] = np.max(shape.normalised(curves[i]))
    return out


def combined(z: np.ndarray, votes: int) -> np.ndarray:
    """The ``votes``-th largest of ``z[N, T]`` per step (``votes = 1``: the maximum)."""
    if not 1 <= votes <= z.shape[0]:
        raise ThresholdError(f"votes must be in 1..{z.shape[0]} (the detectors combined), got {votes}")
    return np.sort(z, axis=0)[z.shape[0] - votes]


@dataclass(frozen=True)
class GroupCurves:
    """The windowed curves of one group (a task): per detector, the shape curves (``I1``) and the conformal
    curves (``I2``), the latter in the same rollout order for every detector."""

    shape: Mapping[str, Sequence[np.ndarray]]
    conformal: Mapping[str, Sequence[np.ndarray]]


@dataclass(frozen=True)
class JointThreshold:
    """A fitted joint combination: ``k``, and per group and detector its shape and threshold ``gamma_d(t)``."""

    k: float
    votes: int
    detectors: tuple[str, ...]
    shapes: dict[str, dict[str, Shape]]
    """``shapes[group][detector]``."""
    thresholds: dict[str, dict[str, Threshold]]
    """``thresholds[group][detector]``: ``gamma_d(t)`` with the settings' extension."""
    scores: np.ndarray
    """``R_i`` of the conformal rollouts, all groups in order."""
    conformal: dict[str, int] = field(default_factory=dict)
    """Conformal rollouts per group."""
    equalisers: dict[str, Equaliser] = field(default_factory=dict)
    """Per detector its equaliser ``T_d`` (empty: not equalised)."""

    @property
    def m(self) -> int:
        """The number of conformal scores ``k`` is the quantile of."""
        return int(self.scores.shape[0])

    def params(self) -> dict[str, Any]:
        """Plain-data summary for a calibration file."""
        return {"k": float(self.k), "votes": self.votes, "m": self.m, "conformal": dict(self.conformal)}


def _group_length(curves: GroupCurves, detectors: Sequence[str]) -> int:
    lengths = [np.asarray(c).shape[0] for d in detectors for part in (curves.shape, curves.conformal) for c in part[d]]
    return max(lengths)


def group_scores(curves: GroupCurves, shapes: Mapping[str, Shape], detectors: Sequence[str], votes: int,
                 equalisers: Mapping[str, Equaliser] | None = None) -> np.ndarray:
    """``R_i = max_t c_i(t)`` of a group's conformal rollouts (each ``z_d`` through ``equalisers[d]`` if given)."""
    counts = {len(curves.conformal[d]) for d in detectors}
    if len(counts) != 1:
        raise ThresholdError(f"every detector needs the same conformal rollouts, got counts {sorted(counts)}")
    out = np.empty(counts.pop())
    for i in range(out.shape[0]):
        z = np.stack([_equalised(shapes[d].normalised(np.asarray(curves.conformal[d][i], dtype=np.float64)),
                                 (equalisers or {}).get(d)) for d in detectors])
        out[i] = np.max(combined(z, votes))
    return out


def _equalised(z: np.ndarray, equaliser: Equaliser | None) -> np.ndarray:
    return z if equaliser is None else equaliser(z)


def fit_equalisers(groups: Mapping[str, GroupCurves], detectors: Sequence[str], kinds: Mapping[str, str],
                   settings: ThresholdSettings, equalise: str, level: float = DEFAULT_LEVEL) -> dict[str, Equaliser]:
    """Per detector the equaliser ``equalise`` over every group's :func:`fold_maxima` of its shape curves (empty for
    ``"none"``); the conformal curves are never read. A detector whose maxima cannot be equalised is refused by
    name."""
    check_equalisation(equalise, level)
    if equalise == "none":
        return {}
    out = {}
    for d in detectors:
        maxima = np.concatenate([fold_maxima(curves.shape[d], max(len(c) for c in curves.shape[d]), kinds[d], settings)
                                 for curves in groups.values()])
        try:
            out[d] = fit_equaliser(equalise, maxima, level)
        except ThresholdError as error:
            raise ThresholdError(f"detector {d!r}: {error}") from error
    return out


def fit_joint(groups: Mapping[str, GroupCurves], detectors: Sequence[str], kinds: Mapping[str, str], votes: int,
              settings: ThresholdSettings, equalise: str = "none", level: float = DEFAULT_LEVEL) -> JointThreshold:
    """One conformal factor ``k`` over the ``votes``-th largest normalised (and with ``equalise`` equalised) score of
    ``detectors``, pooled over ``groups`` (one group: a single task), and every group's per-detector thresholds
    (module docstring).

    ``kinds[d]`` is detector ``d``'s normalisation (:data:`SHAPE_KINDS`); ``settings`` gives delta, the support
    rule, the floor, the extension and whether the quantile is conformal; ``equalise`` and ``level`` the
    equalisation (:data:`~fiper_ros.core.equalisation.EQUALISATIONS`).
    """
    detectors = tuple(detectors)
    if not detectors:
        raise ThresholdError("a joint combination needs at least one detector")
    if not groups:
        raise ThresholdError("a joint combination needs the curves of at least one group")
    combined(np.zeros((len(detectors), 1)), votes)  # refuse impossible votes before any work
    check_equalisation(equalise, level)
    shapes: dict[str, dict[str, Shape]] = {}
    for name, curves in groups.items():
        for d in detectors:
            if not curves.shape[d] or not curves.conformal[d]:
                raise ThresholdError(f"group {name!r}, detector {d!r}: no shape or no conformal curves")
        length = _group_length(curves, detectors)
        shapes[name] = {d: fit_shape(curves.shape[d], length, kinds[d], settings) for d in detectors}
    equalisers = fit_equalisers(groups, detectors, kinds, settings, equalise, level)
    scores = [group_scores(curves, shapes[name], detectors, votes, equalisers) for name, curves in groups.items()]
    pooled = np.concatenate(scores)
    k = _quantile(pooled, settings.delta, settings.conformal)
    factors = {d: equalisers[d].inverse(k) if d in equalisers else k for d in detectors}
    extra = {d: {"factor": factors[d], "equaliser": equalisers[d].to_dict()} for d in equalisers}
    thresholds = {name: {d: Threshold(kinds[d], settings.delta, shape.values(factors[d]), settings.extension,
                                      {"k": float(k), "m": int(pooled.shape[0]), "votes": votes,
                                       "floor": shape.floor, **extra.get(d, {})})
                         for d, shape in group.items()}
                  for name, group in shapes.items()}
    return JointThreshold(float(k), votes, detectors, shapes, thresholds, pooled,
                          {name: int(s.shape[0]) for name, s in zip(groups, scores)}, equalisers)
