"""The sweep of combinations: any detectors under one conformal threshold, or voting with one threshold each,
per task or pooled over tasks (:mod:`fiper_ros.core.combination`).

A :class:`Combination` names detectors (score streams). For every window label, normalisation kind
(:data:`~fiper_ros.core.combination.SHAPE_KINDS`), combine and delta it gets, per task, the first alarm of
every test rollout, exactly as a calibration of that configuration would decide:

- every detector's curves are aggregated as the sweep does (:func:`~fiper_ros.evaluation.sweep.aggregated`,
  bit-identical to the core's windows); a detector whose aggregation is fixed (the elapsed time: cumulative)
  keeps it, and a detector whose normalisation is fixed (the elapsed time: CP scaled) keeps it
  (:data:`fiper_ros.core.detectors.INFO`);
- per task and detector the shape is :func:`~fiper_ros.core.combination.fit_shape` of the fit part's curves
  (cross-fitted where the scores have them);
- joint combines (``max``, ``kth:K``): the conformal score of a conformal rollout is the maximum over its steps of
  the ``votes``-th largest normalised score (the core's formula, vectorised over rollouts), ``k`` the conformal
  quantile of the task's scores, or of every task's scores pooled; ``and`` / ``or``: each detector its own ``k``
  over its own scores (one vote each), AND needing all votes, OR one;
- detector ``d``'s threshold is ``shape.values(k)`` extended with :meth:`~fiper_ros.core.thresholds.Threshold.over`,
  and a step alarms when at least the combine's votes of ``eta_d > gamma_d`` hold (the core's strict comparison);
- an equalised combination (:attr:`Combination.equalise`, joint combines only) maps each detector's normalised
  scores by its equaliser (:func:`~fiper_ros.core.equalisation.fit_equaliser` of the fit part's
  :func:`~fiper_ros.core.combination.fold_maxima`, over every task's when pooled) before the ``votes``-th largest,
  and detector ``d``'s threshold is ``shape.values(T_d^{-1}(k))``, as :func:`~fiper_ros.core.combination.fit_joint`
  fits them;
- an OR of ``N`` detectors at :attr:`~fiper_ros.evaluation.sweep.SweepSettings.or_promise` ``"delta"`` calibrates
  each detector at ``delta / N`` in the column of delta (promise delta, the union bound).

A ``k`` that is ``+inf`` (too few conformal rollouts for delta) is recorded, as in the per-task sweep. On request
(``thresholds``) every configuration's per-detector thresholds are kept, as the per-task sweep keeps them.
"""

from __future__ import annotations

from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from fiper_ros.core.combination import DELTA_FREE_SHAPES, SHAPE_KINDS, Shape, equalisable, fit_shape, fold_maxima
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import info
from fiper_ros.core.equalisation import Equaliser, fit_equaliser
from fiper_ros.core.fusion import Combine
from fiper_ros.core.thresholds import Threshold, ThresholdSettings, _quantile
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.methods import Combination
from fiper_ros.evaluation.sweep import CUMULATIVE, Group, SweepSettings, TaskSweep, aggregated, first_alarms, padded

#: Combines the joint sweep covers by default: the two joint ones and N-detector AND / OR.
JOINT_COMBINE_DEFAULTS = ("max", "kth:2", "and", "or")


def _combines(combination: Combination, wanted: Sequence[str]) -> list[Combine]:
    """The combines of ``wanted`` a combination takes (one detector: its own threshold, the ``max`` of one; an
    equalised combination: the joint ones)."""
    if len(combination.detectors) == 1:
        return [Combine(CombineMode.MAX)]
    combines = [Combine.parse(text) for text in wanted]
    return [c for c in combines if (c.mode is not CombineMode.KTH or c.k <= len(combination.detectors))
            and (c.joint or combination.equalise == "none")]


def _kinds(combination: Combination, wanted: Sequence[str]) -> list[str]:
    """The normalisation kinds a combination is swept with: ``wanted`` that its equalisation applies to, or the one
    its detectors all fix."""
    fixed = {info(d).shape for d in combination.detectors}
    if len(fixed) == 1 and None not in fixed:
        return [fixed.pop()]
    return [kind for kind in wanted if equalisable(combination.equalise, kind)]


@dataclass(frozen=True)
class _Curves:
    """One detector's aggregated curves of one task under one label: padded arrays and the lengths."""

    fit: list[np.ndarray]
    conformal: np.ndarray
    conformal_lengths: np.ndarray
    test: np.ndarray


def _labelled(stream: StreamScores, settings: SweepSettings) -> Iterator[tuple[str, _Curves]]:
    """``(label, curves)`` for every label of ``settings``, the fit, conformal and test parts aggregated alike."""
    if stream.fit is None:
        raise ValueError("a combination needs a split with a fit part (split conformal)")
    fit_lengths = [c.shape[0] for c in stream.fit]
    conformal = padded(stream.conformal)
    lengths = np.array([c.shape[0] for c in stream.conformal])
    parts = zip(aggregated(padded(stream.fit), settings), aggregated(conformal, settings),
                aggregated(padded(stream.test), settings))
    for (label, fit), (_, conf), (_, test) in parts:
        yield label, _Curves([fit[i, :n] for i, n in enumerate(fit_lengths)], conf, lengths, test)


def _normalised(curves: _Curves, shape: Shape) -> np.ndarray:
    """``z`` of the padded conformal curves ``[M, L]`` (NaN after each end), the core's formula."""
    width = curves.conformal.shape[1]  # the longest conformal curve, never longer than the shape
    return (curves.conformal - shape.offset[None, :width]) / shape.scale[None, :width]


def _scores(z: np.ndarray, votes: int) -> np.ndarray:
    """``max_t`` of the ``votes``-th largest of ``z[N, M, L]`` (NaN padding ignored): ``R`` per conformal rollout."""
    ranked = np.sort(z, axis=0)[z.shape[0] - votes]
    return np.nanmax(ranked, axis=1)


def _alarms(test: Sequence[np.ndarray], thresholds: Sequence[np.ndarray], votes: int) -> np.ndarray:
    """First alarm per test rollout (-1: none): at least ``votes`` detectors above their thresholds at a step."""
    counts = np.zeros(test[0].shape, dtype=np.int32)
    for eta, gamma in zip(test, thresholds):
        counts += np.greater(eta, gamma[None, :])
    return first_alarms(counts >= votes)


def _length(curves: Mapping[str, _Curves]) -> int:
    """The shape length of a task: its longest fit or conformal curve."""
    any_curves = next(iter(curves.values()))
    return max(max(c.shape[0] for c in any_curves.fit), int(any_curves.conformal_lengths.max()))


def joint_sweep(streams: Mapping[str, Mapping[str, StreamScores]], combinations: Sequence[Combination],
                settings: SweepSettings, bases: Mapping[str, ThresholdSettings], pooled: bool,
                combines: Sequence[str] = JOINT_COMBINE_DEFAULTS,
                kinds: Sequence[str] = SHAPE_KINDS, thresholds: bool = False) -> dict[str, TaskSweep]:
    """Every configuration of ``combinations`` on one seed's ``streams[task][stream]``: per task its groups,
    first alarms ``[groups, deltas, test rollouts]``, infinite thresholds and conformal counts (and with
    ``thresholds`` each group's thresholds ``[deltas, detectors, T]``, :attr:`TaskSweep.thresholds`).

    ``bases[task]`` carries the threshold rules (support, floor, extension, conformal quantile); ``pooled``:
    ``k`` over every task's conformal rollouts (each task normalised by its own shapes), else per task.
    """
    tasks = list(streams)
    for kind in kinds:
        if kind not in SHAPE_KINDS:
            raise ValueError(f"a combination normalises with one of {', '.join(SHAPE_KINDS)}, not {kind!r}")
    needed = sorted({d for c in combinations for d in c.detectors})
    swept = [d for d in needed if info(d).aggregation is None]
    # A detector with a fixed aggregation has one set of curves whatever the label.
    fixed_settings = SweepSettings(windows=(1,), cumulative=True, deltas=settings.deltas, max_pool=())
    fixed = {(t, d): dict(_labelled(streams[t][d], fixed_settings))[CUMULATIVE]
             for t in tasks for d in needed if d not in swept}
    generators = {(t, d): _labelled(streams[t][d], settings) for t in tasks for d in swept}
    parts = ("groups", "alarms", "infinite", "conformal", *(("thresholds",) if thresholds else ()))
    out: dict[str, dict[str, list]] = {t: {part: [] for part in parts} for t in tasks}
    for position, label in enumerate(settings.labels()):
        current = {key: next(generator)[1] for key, generator in generators.items()}
        maxima: dict[tuple, np.ndarray] = {}  # fold maxima, shared by the combinations of this label
        for combination in combinations:
            windowed = any(d in swept for d in combination.detectors)
            if not windowed and position > 0:
                continue  # every detector's aggregation is fixed: one configuration, swept once
            chosen = {t: {d: current[(t, d)] if d in swept else fixed[(t, d)] for d in combination.detectors}
                      for t in tasks}
            for kind in _kinds(combination, kinds):
                _configurations(combination, label if windowed else CUMULATIVE, kind, chosen, settings, bases,
                                pooled, _combines(combination, combines), out, maxima)
    return {t: TaskSweep(own["groups"], np.stack(own["alarms"]), np.stack(own["infinite"]),
                         np.array(own["conformal"], dtype=int), own.get("thresholds")) for t, own in out.items()}


def _equalisers(combination: Combination, kinds: Mapping[str, str], chosen: Mapping[str, Mapping[str, _Curves]],
                bases: Mapping[str, ThresholdSettings], delta: float, pooled: bool,
                maxima: dict[tuple, np.ndarray]) -> dict[tuple[str, str], Equaliser]:
    """Per (task, detector) the equaliser of an equalised combination, over the task's fit-part fold maxima or, pooled,
    every task's (``maxima`` caches them: a band's or a constant's do not depend on delta)."""
    tasks = list(chosen)
    out = {}
    for pool in [tasks] if pooled else [[t] for t in tasks]:
        for d in combination.detectors:
            parts = []
            for t in pool:
                key = (t, d, kinds[d], None if kinds[d] in DELTA_FREE_SHAPES else delta)
                if key not in maxima:
                    fit = chosen[t][d].fit
                    maxima[key] = fold_maxima(fit, max(c.shape[0] for c in fit), kinds[d],
                                              replace(bases[t], delta=delta))
                parts.append(maxima[key])
            equaliser = fit_equaliser(combination.equalise, np.concatenate(parts), combination.level)
            out.update({(t, d): equaliser for t in pool})
    return out


def _configurations(combination: Combination, label: str, kind: str, chosen: Mapping[str, Mapping[str, _Curves]],
                    settings: SweepSettings, bases: Mapping[str, ThresholdSettings], pooled: bool,
                    combines: Sequence[Combine], out: dict[str, dict[str, list]], maxima: dict[tuple, np.ndarray]
                    ) -> None:
    """Append every combine's group of one (combination, label, kind) to ``out``, per task (``maxima``: the fold
    maxima of the label, cached). In the column of delta each threshold is calibrated at
    :meth:`~fiper_ros.evaluation.sweep.SweepSettings.threshold_delta` (an OR at promise delta: ``delta / N``, its
    shapes too, as a calibration at that delta fits them)."""
    tasks = list(chosen)
    detectors = combination.detectors
    kinds = {d: info(d).shape or kind for d in detectors}
    fixed = {(t, d): fit_shape(chosen[t][d].fit, _length(chosen[t]), kinds[d], bases[t])
             for t in tasks for d in detectors if kinds[d] in DELTA_FREE_SHAPES}
    alarms: dict[tuple[str, str], list[np.ndarray]] = {(t, str(c)): [] for t in tasks for c in combines}
    kept: dict[tuple[str, str], list[np.ndarray]] = {(t, str(c)): [] for t in tasks for c in combines}
    infinite: dict[tuple[str, str], list[bool]] = {(t, str(c)): [] for t in tasks for c in combines}
    behind: dict[tuple[str, str], int] = {}

    def normalised(level: float) -> tuple[dict[str, dict[str, Shape]], dict[tuple[str, str], Equaliser],
                                          dict[str, np.ndarray]]:
        """Shapes, equalisers and normalised conformal curves ``z[task]`` ``[detectors, M, L]`` at ``level``."""
        shapes = {t: {d: fixed.get((t, d)) or fit_shape(chosen[t][d].fit, _length(chosen[t]), kinds[d],
                                                      replace(bases[t], delta=level))
                      for d in detectors} for t in tasks}
        equalisers = {} if combination.equalise == "none" else \
            _equalisers(combination, kinds, chosen, bases, level, pooled, maxima)
        z = {t: np.stack([_normalised(chosen[t][d], shapes[t][d]) if (t, d) not in equalisers
                          else equalisers[(t, d)](_normalised(chosen[t][d], shapes[t][d])) for d in detectors])
             for t in tasks}
        return shapes, equalisers, z

    delta_free = all(kinds[d] in DELTA_FREE_SHAPES for d in detectors)  # the same shapes and z at every level
    for delta in settings.deltas:
        levels: dict[float, tuple] = {}
        for combine in combines:
            level = settings.threshold_delta(delta, str(combine), len(detectors))
            key = delta if delta_free else level
            if key not in levels:
                levels[key] = normalised(key)
            shapes, equalisers, z = levels[key]
            votes = combine.votes(len(detectors))
            # joint: one k over the votes-th largest; and / or: one k per detector over its own scores
            members = [slice(None)] if combine.joint else [slice(i, i + 1) for i in range(len(detectors))]
            ks: dict[str, list[float]] = {t: [] for t in tasks}
            for member in members:
                scores = {t: _scores(z[t][member], votes if combine.joint else 1) for t in tasks}
                for t in tasks:
                    own = np.concatenate(list(scores.values())) if pooled else scores[t]
                    ks[t].append(_quantile(own, level, bases[t].conformal))
                    behind[(t, str(combine))] = int(own.shape[0])
            for t in tasks:
                per_detector = ks[t] * len(detectors) if combine.joint else ks[t]
                if equalisers:
                    per_detector = [equalisers[(t, d)].inverse(k) for d, k in zip(detectors, per_detector)]
                test_length = chosen[t][detectors[0]].test.shape[1]
                gammas = [Threshold(kinds[d], level, shapes[t][d].values(k), bases[t].extension).over(test_length)
                          for d, k in zip(detectors, per_detector)]
                alarms[(t, str(combine))].append(_alarms([chosen[t][d].test for d in detectors], gammas, votes))
                if "thresholds" in out[t]:
                    kept[(t, str(combine))].append(np.stack(gammas))
                infinite[(t, str(combine))].append(not all(np.isfinite(k) for k in per_detector))
    for t in tasks:
        for combine in combines:
            key = (t, str(combine))
            shown = str(combine) if len(detectors) > 1 else ""  # one detector: its own threshold, no combine
            out[t]["groups"].append(Group(combination.name, label, kind, shown))
            out[t]["alarms"].append(np.stack(alarms[key]))
            out[t]["infinite"].append(np.array(infinite[key]))
            out[t]["conformal"].append(behind[key])
            if "thresholds" in out[t]:
                out[t]["thresholds"].append(np.stack(kept[key]))
