"""``fiper evaluate --auto``: each task's configuration chosen by ``fiper calibrate --auto`` on that task's
calibration successes alone, reported on its test rollouts beside the protocols that read labels.

Per task, seed and swept delta, the choice is :func:`fiper_ros.core.auto.choose` on the scores of
:func:`fiper_ros.core.calibration.auto.auto_scores` (the fit part of the task's split, fold models, failure
proxies): the functions ``fiper calibrate --auto`` calls, on the same successes, split and seed, among the
detectors the run scores that a calibration can declare. The chosen configuration is calibrated as
:func:`fiper_ros.core.calibration.calibrate` does it (its shapes from the fold curves, its conformal quantile from
the conformal part's curves of the run's score streams, :func:`fiper_ros.core.calibration.fit.fit_thresholds`),
and its first alarm on every test rollout is the core's decision (``eta > gamma``, the combine's votes). No
label of the task, and no rollout of another task, enters the choice.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fiper_ros.core.auto import AutoChoice, AutoSettings, TaskScores, choose
from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.calibration.auto import auto_scores, auto_split_settings, chosen_settings
from fiper_ros.core.calibration.fit import fit_thresholds, split_successes
from fiper_ros.core.detectors import ACE, declarable
from fiper_ros.core.fusion import exceeds, fuse_votes
from fiper_ros.core.profiles import get_profile
from fiper_ros.core.scorers import FitContext
from fiper_ros.core.window import aggregate
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.early import EarlyDetection
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.progress import Progress
from fiper_ros.evaluation.protocol import METRICS, alarm_metrics, nanmean
from fiper_ros.evaluation.scoring import robot_for, torch_threads


def candidate_streams(streams: Sequence[str]) -> tuple[str, ...]:
    """The streams of a run that a calibration can declare (the ``--auto`` candidates), in order."""
    return tuple(s for s in streams if declarable(s))


@dataclass
class AutoOutcome:
    """``--auto`` over every task, seed and delta: the choice and its metrics.

    ``metrics[subset]`` ``[tasks, seeds, deltas, 5]`` (NaN where the chosen threshold is +inf), ``held_out[subset]``
    ``[tasks, seeds, deltas]`` the false-alarm rate on the subset's ID successes, ``choices[task][seed][delta]`` the
    chosen configuration's label and ``records[task][seed][delta]`` its record (its best five candidates); a task's
    choice is shown at the delta :meth:`shown` names. ``early``: the threshold-free figures of the choices shown, on
    all test rollouts (``None``: some choice is not a configuration of the sweep, which measures them)."""

    deltas: tuple[float, ...]
    choices: list[list[list[str]]]
    metrics: dict[str, np.ndarray]
    infinite: np.ndarray
    held_out: dict[str, np.ndarray]
    records: list[list[list[dict[str, Any]]]]
    seconds: float
    early: EarlyDetection | None = None

    def shown(self, task: int) -> int:
        """The delta (an index) a task's choice is shown at: the one closest to 0.05 whose threshold is finite on
        every seed (0.05 itself where there is none)."""
        finite = [k for k in range(len(self.deltas)) if not self.infinite[task, :, k].any()]
        return min(finite or range(len(self.deltas)), key=lambda k: (abs(self.deltas[k] - 0.05), k))

    def values(self, subset: str) -> np.ndarray:
        """Metrics averaged over the finite deltas, ``[tasks, seeds, 5]``."""
        return nanmean(self.metrics[subset], axis=2)


def _first_alarms(curves: dict[str, list[np.ndarray]], thresholds: dict[str, Any], votes: int) -> np.ndarray:
    """The first alarm step of every rollout (-1: none) under the core's decisions."""
    count = len(next(iter(curves.values())))
    out = np.full(count, -1, dtype=np.int64)
    for i in range(count):
        decisions = [exceeds(curves[d][i], thresholds[d].over(curves[d][i].shape[0])) for d in curves]
        alarms = np.flatnonzero(fuse_votes(decisions, votes))
        if alarms.size:
            out[i] = alarms[0]
    return out


def _windowed(scores: Sequence[np.ndarray], detector: str, settings: Any) -> list[np.ndarray]:  # settings
    return [aggregate(np.asarray(s, dtype=np.float64), settings.aggregation_of(detector), settings.window_of(detector))
            for s in scores]


#: Per task calibrated together (the judged task alone; every task, with thresholds pooled over the tasks): the
#: per-step scores of its fit part (the shapes) per detector, and its score streams.
Fitted = Mapping[str, tuple[Mapping[str, Sequence[np.ndarray]], Mapping[str, StreamScores]]]


def calibrated_alarms(dataset: Dataset, fitted: Fitted, settings: CalibrationSettings) -> tuple[np.ndarray, bool]:
    """The first alarm on every test rollout of ``dataset`` of the configuration ``settings``, calibrated as
    :func:`fiper_ros.core.calibration.calibrate` does it on the tasks of ``fitted`` (which holds ``dataset``'s): its
    shapes from their fit part's per-step scores, its conformal quantile from their conformal part's curves; whether
    its threshold is +inf (then no alarm)."""
    shapes = {name: {d: _windowed(shape[d], d, settings) for d in settings.detectors}
              for name, (shape, _) in fitted.items()}
    conformal = {name: {d: _windowed(streams[d].conformal, d, settings) for d in settings.detectors}
                 for name, (_, streams) in fitted.items()}
    thresholds, _ = fit_thresholds(conformal, shapes, settings)
    own = thresholds[dataset.task]
    if not all(np.isfinite(t.values).all() for t in own.values()):
        return np.full(len(dataset.test), -1, dtype=np.int64), True
    streams = fitted[dataset.task][1]
    test = {d: _windowed(streams[d].test, d, settings) for d in settings.detectors}
    return _first_alarms(test, own, settings.votes), False


def task_choice(dataset: Dataset, data: TaskScores, streams: dict[str, StreamScores], pool: tuple[str, ...],
                method_settings: MethodSettings, auto: AutoSettings, seed: int, delta: float
                ) -> tuple[AutoChoice, np.ndarray, bool]:
    """The choice at ``delta`` and its first alarm on every test rollout; whether its threshold is +inf."""
    base = replace(method_settings.calibration_settings(seed), delta=delta)
    choice = choose({dataset.task: data}, pool, auto, base.threshold_settings(), seed)
    alarms, infinite = calibrated_alarms(dataset, {dataset.task: (data.successes, streams)},
                                         chosen_settings(base, choice))
    return choice, alarms, infinite


def task_scores(dataset: Dataset, pool: tuple[str, ...], method_settings: MethodSettings, auto: AutoSettings,
                seed: int, threads: int = 1) -> TaskScores:
    """The rule's scores of ``dataset``'s fit part for ``seed`` (the fold models of ``fiper calibrate --auto``)."""
    settings = auto_split_settings(method_settings.calibration_settings(seed), auto)
    good = dataset.calibration_successes
    split = split_successes(len(good), settings)
    robot = robot_for(dataset, method_settings) if ACE in pool else None
    fk = None if robot is None else robot.forward_kinematics()
    context = FitContext(seed, get_profile(method_settings.profile), method_settings.detector_options(robot),
                         dataset.action_space, fk)
    with torch_threads(threads):
        return auto_scores(good, split.fit, split.shape_folds, pool, context, fk, auto, seed)


#: Per task (its index and dataset) and seed: for every delta the chosen configuration's label, its record, its
#: first alarm on every test rollout and whether its threshold is +inf.
Choices = Callable[[int, Dataset, int], tuple[list[str], list[dict[str, Any]], np.ndarray, np.ndarray]]


def evaluate_choices(datasets: Sequence[Dataset], method_settings: MethodSettings, seeds: Sequence[int],
                     deltas: Sequence[float], subsets: dict[str, list[np.ndarray | None]],
                     held_out: dict[str, list[np.ndarray]], choices: Choices, progress: bool = True) -> AutoOutcome:
    """Every task's and seed's ``choices`` (a rule's, at every delta) and their metrics on ``subsets`` of every task's
    test rollouts (``None``: all) and false alarms on ``held_out`` ID successes."""
    started = time.perf_counter()
    profile = get_profile(method_settings.profile)
    bar = Progress("auto", len(datasets) * len(seeds), progress)
    metrics = {name: np.full((len(datasets), len(seeds), len(deltas), len(METRICS)), np.nan) for name in subsets}
    rates = {name: np.full((len(datasets), len(seeds), len(deltas)), np.nan) for name in held_out}
    infinite = np.zeros((len(datasets), len(seeds), len(deltas)), dtype=bool)
    labels: list[list[list[str]]] = []
    records: list[list[list[dict[str, Any]]]] = []
    tnr = METRICS.index("tnr")
    for t, dataset in enumerate(datasets):
        horizons = dataset.lengths if profile.dt_mode == "paper" else dataset.max_length
        labels.append([])
        records.append([])
        for s, seed in enumerate(seeds):
            chosen, made, alarms, infinite[t, s] = choices(t, dataset, seed)
            labels[t].append(chosen)
            records[t].append(made)
            for name, per_task in subsets.items():
                values = alarm_metrics(alarms, dataset.failed, horizons, profile.dt_mode, per_task[t],
                                       profile.metrics_rule)
                values[infinite[t, s]] = np.nan
                metrics[name][t, s] = values
            for name, members in held_out.items():
                rate = 1.0 - alarm_metrics(alarms, dataset.failed, horizons, profile.dt_mode, members[t])[..., tnr]
                rate[infinite[t, s]] = np.nan
                rates[name][t, s] = rate
            bar.advance(note=f"{dataset.task} seed {seed}")
    bar.close()
    return AutoOutcome(tuple(deltas), labels, metrics, infinite, rates, records, time.perf_counter() - started)


def auto_evaluation(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
                    streams: Sequence[str], method_settings: MethodSettings, seeds: Sequence[int],
                    deltas: Sequence[float], auto: AutoSettings, subsets: dict[str, list[np.ndarray | None]],
                    held_out: dict[str, list[np.ndarray]], threads: int = 1, progress: bool = True) -> AutoOutcome:
    """``--auto`` on every task and seed (module docstring); metrics on ``subsets`` of every task's test rollouts
    (``None``: all) and false alarms on ``held_out`` ID successes."""
    pool = candidate_streams(streams)

    def choices(t: int, dataset: Dataset, seed: int) -> tuple[list[str], list[dict[str, Any]], np.ndarray,
                                                              np.ndarray]:
        data = task_scores(dataset, pool, method_settings, auto, seed, threads)
        alarms = np.full((len(deltas), len(dataset.test)), -1, dtype=np.int64)
        infinite = np.zeros(len(deltas), dtype=bool)
        made = []
        for k, delta in enumerate(deltas):
            choice, alarms[k], infinite[k] = task_choice(dataset, data, scores[(dataset.task, seed)], pool,
                                                         method_settings, auto, seed, delta)
            made.append(choice)
        return [c.chosen.label() for c in made], [c.record(top=5) for c in made], alarms, infinite

    return evaluate_choices(datasets, method_settings, seeds, deltas, subsets, held_out, choices, progress)
