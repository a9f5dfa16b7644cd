"""Early detection, threshold-free: each configuration's AUROC and q-AUC (:func:`fiper_ros.core.metrics.auroc`).

A configuration's *statistic* of a test rollout is the maximum over the rollout's steps of what its thresholds
are laid on, without the thresholds:

- a single-stream method (per-task thresholds): its windowed score ``eta(t)`` at the configuration's window
  (every threshold kind of a window has the same statistic); the elapsed time: its step count;
- a combination (:mod:`.joint_sweep`), a method swept with thresholds pooled over tasks, and FIPER: the combined
  statistic ``c(t)``, the ``votes``-th largest of the detectors' normalised scores ``z_d(t) = (eta_d(t) -
  offset_d(t)) / scale_d(t)`` (:func:`fiper_ros.core.combination.combined`): ``max`` and OR one vote, ``kth:K``
  ``K``, AND every detector's. The shape (:func:`fiper_ros.core.combination.fit_shape`, the configuration's kind
  or the one a detector fixes) is fitted on the fit part's curves (all calibration curves where the split has no
  fit part) at the calibration's delta (only CP scaled's shape depends on it), and extended past its length by
  the threshold's extension rule. FIPER with time-varying thresholds has no shape that puts its two scores on
  one scale: no statistic, a null AUROC.

The AUROC takes every rollout's maximum over all its steps; the q-AUC its maximum over its first
``ceil(q T_max)`` steps (:func:`fiper_ros.core.metrics.early_cut`, ``T_max`` the longest test rollout of its
task). Pooled over tasks, the rollouts of every task enter one AUROC (each task's under its own
configuration where a protocol chooses per task), each task's statistic on a scale the tasks share: a statistic
already normalised by a shape (a combination's, FIPER's, a method's with thresholds pooled over tasks) as it is; a
single stream's raw windowed score, fitted per task on scales of its own (a step count, a distance, another
detector where a protocol chooses per task), mapped by its task's CP constant shape, ``(m - mean) / std`` of the
fit part's maxima (:meth:`TaskStatistics.pooling`): one increasing map per task, so each task's own AUROC and
q-AUC are unchanged. Neither says anything about the false-alarm promise.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from fiper_ros.core.combination import SHAPE_KINDS, Shape, combined, fit_shape
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import info
from fiper_ros.core.fusion import Combine
from fiper_ros.core.metrics import auroc, early_cut, rollout_peaks
from fiper_ros.core.thresholds import Threshold, ThresholdSettings
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.methods import method_of
from fiper_ros.evaluation.sweep import CUMULATIVE, FIPER, FIPER_STREAMS, MAX_POOL, Group, SweepSettings, aggregated, \
    padded

#: q of the q-AUC by default: the first quarter of the longest rollout.
DEFAULT_Q = 0.25
#: Aggregated curves kept at once while statistics are computed (each ``[N, T]`` float64): bounds the memory.
_KEPT_CURVES = 256


@dataclass(frozen=True)
class Statistic:
    """How a configuration's statistic is formed: per detector its stream, window label and normalisation kind
    (``None``: the raw windowed score), and the votes the combined statistic counts."""

    detectors: tuple[str, ...]
    labels: tuple[str, ...]
    kinds: tuple[str | None, ...]
    votes: int


def statistic_of(group: Group, combinations: Mapping[str, tuple[str, ...]]) -> Statistic | None:
    """The statistic of ``group`` (module docstring); ``combinations`` names the detectors of every method swept as
    a combination (the run's combinations, and every method when thresholds are pooled; none: an equalised
    combination). ``None``: FIPER with a threshold kind that has no shape, or an equalised combination (its maxima of
    the equalised scores are not computed here)."""
    if group.method in combinations:
        detectors = combinations[group.method]
        if not detectors:
            return None
        labels = tuple(CUMULATIVE if info(d).aggregation else group.window for d in detectors)
        kinds: tuple[str | None, ...] = tuple(info(d).shape or group.kind for d in detectors)
        return Statistic(detectors, labels, kinds, Combine.parse(group.combine or CombineMode.MAX).votes(len(detectors)))
    if group.method == FIPER:
        if group.kind not in SHAPE_KINDS:
            return None
        return Statistic(FIPER_STREAMS, tuple(group.window.split("/")), (group.kind, group.kind),
                         Combine.parse(group.combine).votes(len(FIPER_STREAMS)))
    return Statistic(method_of(group.method).streams, (group.window,), (None,), 1)


def _grid(label: str, deltas: tuple[float, ...]) -> SweepSettings:
    """A sweep grid whose aggregation yields ``label`` (among at most two labels)."""
    if label == CUMULATIVE:
        return SweepSettings(windows=(1,), cumulative=True, deltas=deltas, max_pool=())
    if label.startswith(MAX_POOL):
        return SweepSettings(windows=(1,), cumulative=False, deltas=deltas, max_pool=(int(label.removeprefix(MAX_POOL)),))
    return SweepSettings(windows=(int(label),), cumulative=False, deltas=deltas, max_pool=())


def _aggregated(curves: list[np.ndarray], label: str, deltas: tuple[float, ...]) -> np.ndarray:
    """Padded curves ``[N, T]`` aggregated as the sweep aggregates them under ``label``."""
    return next(eta.copy() for name, eta in aggregated(padded(curves), _grid(label, deltas)) if name == label)


class TaskStatistics:
    """Statistics of one task and seed, computed on demand for any configurations (kept curves bounded)."""

    def __init__(self, streams: Mapping[str, StreamScores], base: ThresholdSettings, q: float) -> None:
        self.streams = streams
        self.base = base
        any_stream = next(iter(streams.values()))
        self.lengths = np.array([c.shape[0] for c in any_stream.test])
        self.cut = early_cut(int(self.lengths.max()), q)
        self.shape_length = max(c.shape[0] for c in (*(any_stream.fit or ()), *any_stream.conformal))
        self._curves: dict[tuple[str, str, str | None], np.ndarray] = {}

    def _shape(self, stream: str, label: str, kind: str) -> Shape:
        """``kind``'s shape of ``stream`` under ``label``, fitted on the fit part's curves (all calibration curves
        where the split has no fit part)."""
        scores = self.streams[stream]
        source = scores.fit if scores.fit is not None else scores.conformal
        shape_curves = _aggregated(source, label, (self.base.delta,))
        return fit_shape([row[:c.shape[0]] for row, c in zip(shape_curves, source)], self.shape_length, kind, self.base)

    def _curve(self, stream: str, label: str, kind: str | None) -> np.ndarray:
        """The test rollouts' windowed score ``[N, T]`` of ``stream`` under ``label``, normalised by ``kind``'s shape."""
        key = (stream, label, kind)
        if key not in self._curves:
            if len(self._curves) >= _KEPT_CURVES:
                self._curves.clear()
            eta = _aggregated(self.streams[stream].test, label, (self.base.delta,))
            if kind is not None:
                shape = self._shape(stream, label, kind)
                eta = (eta - self._over(shape, shape.offset, eta.shape[1])) / self._over(shape, shape.scale, eta.shape[1])
            self._curves[key] = eta
        return self._curves[key]

    def pooling(self, group: Group, combinations: Mapping[str, tuple[str, ...]]) -> tuple[float, float]:
        """``(offset, scale)`` that put ``group``'s statistic on the scale pooled AUROCs share (module docstring):
        a raw single-stream statistic's CP constant shape on this task, ``(0, 1)`` for a normalised one."""
        statistic = statistic_of(group, combinations)
        if statistic is None or len(statistic.detectors) != 1 or statistic.kinds[0] is not None:
            return 0.0, 1.0
        shape = self._shape(statistic.detectors[0], statistic.labels[0], "cp_constant")
        return float(shape.offset[0]), float(shape.scale[0])

    def _over(self, shape: Shape, values: np.ndarray, length: int) -> np.ndarray:
        """A shape's per-step ``values`` over ``length`` steps, extended by the threshold's extension rule."""
        return Threshold(shape.kind, self.base.delta, values, self.base.extension).over(length)

    def peaks(self, groups: Sequence[Group], combinations: Mapping[str, tuple[str, ...]],
              subset: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Whole-rollout and early maxima ``[groups, rollouts]`` of the test rollouts ``subset`` (default all), NaN
        rows for a configuration without statistic."""
        index = np.arange(self.lengths.shape[0]) if subset is None else np.asarray(subset, dtype=int)
        whole = np.full((len(groups), index.shape[0]), np.nan)
        early = np.full((len(groups), index.shape[0]), np.nan)
        order = sorted(range(len(groups)), key=lambda g: (groups[g].method, groups[g].window))  # reuse of curves
        for g in order:
            statistic = statistic_of(groups[g], combinations)
            if statistic is None:
                continue
            z = np.stack([self._curve(d, label, kind)[index]
                          for d, label, kind in zip(statistic.detectors, statistic.labels, statistic.kinds)])
            curve = combined(z, statistic.votes)
            whole[g] = rollout_peaks(curve, self.lengths[index])
            early[g] = rollout_peaks(curve, self.lengths[index], self.cut)
        return whole, early


def areas(whole: np.ndarray, early: np.ndarray, failed: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """AUROC and q-AUC ``[groups]`` of maxima ``[groups, N]`` (NaN: an empty class, or no statistic)."""
    out = []
    for peaks in (whole, early):
        defined = ~np.isnan(peaks).any(axis=1)
        values = np.full(peaks.shape[0], np.nan)
        if defined.any():
            values[defined] = auroc(peaks[defined], failed)
        out.append(values)
    return out[0], out[1]


@dataclass
class EarlyDetection:
    """One reported configuration's threshold-free figures: ``auroc`` and ``q_auc`` ``[tasks, seeds]`` per task,
    ``pooled_auroc`` and ``pooled_q_auc`` ``[seeds]`` over every task's rollouts; NaN where a class is empty or the
    configuration has no statistic (``defined``)."""

    auroc: np.ndarray
    q_auc: np.ndarray
    pooled_auroc: np.ndarray
    pooled_q_auc: np.ndarray
    defined: bool
    classes: np.ndarray
    """``[tasks, 2]``: failures and successes among each task's reported rollouts (an empty class: a NaN AUROC)."""


def early_detection(statistics: Mapping[int, Sequence[TaskStatistics]], groups: Mapping[int, Sequence[Group]],
                    failed: Sequence[np.ndarray], subsets: Sequence[np.ndarray | None],
                    combinations: Mapping[str, tuple[str, ...]]) -> EarlyDetection:
    """The figures of one reported configuration: ``groups[seed][t]`` on task ``t`` for ``seed`` (the same one
    everywhere unless a protocol chooses per task, or ``--auto`` per task and seed), on its test rollouts
    ``subsets[t]`` (``None``: all) with outcomes ``failed[t]`` (every test rollout's); ``statistics[seed][t]``
    computes the maxima."""
    seeds = sorted(statistics)
    tasks = len(groups[seeds[0]])
    per_task = np.full((2, tasks, len(seeds)), np.nan)
    pooled = np.full((2, len(seeds)), np.nan)
    classes = np.zeros((tasks, 2), dtype=int)
    for s, seed in enumerate(seeds):
        maxima: list[tuple[np.ndarray, np.ndarray]] = []
        labels: list[np.ndarray] = []
        for t in range(tasks):
            whole, early = statistics[seed][t].peaks([groups[seed][t]], combinations, subsets[t])
            outcome = failed[t] if subsets[t] is None else failed[t][subsets[t]]
            per_task[:, t, s] = [area[0] for area in areas(whole, early, outcome)]
            offset, scale = statistics[seed][t].pooling(groups[seed][t], combinations)
            maxima.append(((whole[0] - offset) / scale, (early[0] - offset) / scale))
            labels.append(outcome)
            classes[t] = int(outcome.sum()), int((~outcome).sum())
        both = areas(np.concatenate([m[0] for m in maxima])[None], np.concatenate([m[1] for m in maxima])[None],
                     np.concatenate(labels))
        pooled[:, s] = [area[0] for area in both]
    defined = all(statistic_of(g, combinations) is not None for row in groups.values() for g in row)
    return EarlyDetection(per_task[0], per_task[1], pooled[0], pooled[1], defined, classes)
