"""Metrics of the sweep and the evaluation protocols (Sec. 5 "Evaluation Protocol", App. B.4, C).

Metrics come from :func:`fiper_ros.core.metrics.evaluate` on the sweep's first-alarm steps (identical
alarm vectors are evaluated once). DT uses each rollout's own length ``T`` in the paper profile
(``t / T``) and ``T_max`` over calibration and test in the reference profile (``t / (T_max - 1)``); the
reference profile's metrics rule also gives the authors' values for empty classes (TPR / TNR 0, DT 1.0) and
rounds to 6 decimals, so a subset without failures has a TWA there (NaN in the paper profile).

Protocols:

- ``"paper"``: every configuration's metrics are averaged over the deltas; each method's window and
  threshold type (for FIPER also the window pair and AND/OR) is the one with the highest mean TWA
  across tasks (and seeds); that configuration is reported per task on the same test rollouts.
- ``"clean"``: the same selection on a validation half of every task's test rollouts (a seeded split,
  stratified by outcome), reported on the disjoint other half.
- ``"loto"`` (leave one task out): for every task, the same selection on the other tasks' test rollouts (their
  mean TWA), reported on that task's test rollouts: no number of a task rests on a choice that read its labels.
  It needs two tasks or more. The task's calibration successes do enter the choice, as in every protocol: a
  configuration whose threshold is +inf at every delta on the reported task is never chosen for it.
- ``"clean-task"``: the clean protocol's halves, but each task's configuration is selected on that task's own
  validation half alone (what a user who holds labelled failures of the task would choose for it), reported on
  its report half. It is the reference a configuration chosen without the task's failures (``"loto"``,
  ``--auto``) is measured against, and the per-task ceiling's honest counterpart: the report half never served
  the choice.
- ``"paper-task"``: the paper protocol chosen per task: each task's configuration is the one with the highest TWA on
  that task's own test rollouts, reported on the same rollouts. It reads every label it reports on, so it is no
  result but a ceiling: no configuration a protocol may select (``--select-cumulative`` adds the cumulative ones),
  however chosen, reports more on a task (per method, its
  figure is at least the paper and leave-one-task-out protocols' on every task), and a target above it needs
  another detector or other data, not another rule of choice.

A fixed default configuration (window and threshold type given, FIPER ``w/w`` with AND) is reported
too. A method with a single configuration (the elapsed-time baseline) is reported with it in both. With
several seeds, values are mean and standard deviation over seeds; the task average is taken per seed first.

No silent infinities: a (configuration, task, seed, delta) whose threshold is +inf (too few conformal
rollouts for delta) has no metrics (NaN): it is never part of an average over deltas, and a
configuration that has no finite delta on some task and seed is never selected. :class:`MethodResult`
keeps which of its cells were infinite, so the report shows them.

The promise: for every reported configuration the false-alarm rate on the held-out ID
successes (the test set's successful ID-scenario rollouts; with the clean protocol those of the report
half) per delta, to set beside delta.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.metrics import evaluate
from fiper_ros.evaluation.methods import METHODS
from fiper_ros.evaluation.sweep import FIPER, Group

METRICS = ("twa", "acc", "dt", "tpr", "tnr")
PROTOCOLS = ("paper", "clean", "loto", "clean-task", "paper-task")
#: Per protocol, the subset of every task's test rollouts a configuration is selected on and the one it is reported
#: on (:class:`~fiper_ros.evaluation.engine.SweepOutcome`); ``"loto"`` selects on the other tasks' subset.
SUBSETS = {"paper": ("all", "all"), "clean": ("validation", "report"), "loto": ("all", "all"),
           "clean-task": ("validation", "report"), "paper-task": ("all", "all")}
#: The protocols that choose each task's configuration on its own (:attr:`MethodResult.task_groups`).
PER_TASK = ("loto", "clean-task", "paper-task")


def nanmean(values: np.ndarray, axis: int | tuple[int, ...]) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices stay NaN
        return np.nanmean(values, axis=axis)


def nanstd(values: np.ndarray, axis: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanstd(values, axis=axis)


def alarm_metrics(
    alarms: np.ndarray, failed: np.ndarray, horizons: np.ndarray | int, dt_mode: str, subset: np.ndarray | None = None,
    metrics_rule: str = "paper",
) -> np.ndarray:
    """:data:`METRICS` ``[..., 5]`` of first-alarm steps ``[..., N]`` (-1: none) with the core's ``evaluate``
    (``metrics_rule``: its empty classes and rounding, the profile's)."""
    index = np.arange(alarms.shape[-1]) if subset is None else np.asarray(subset)
    # Not reshape(-1, n): an empty subset (a task without ID test successes) has no -1 to resolve.
    flat = alarms[..., index].reshape(int(np.prod(alarms.shape[:-1])), index.shape[0])
    outcomes = [bool(f) for f in failed[index]]
    t_max: int | list[int] = horizons if isinstance(horizons, int) else [int(h) for h in horizons[index]]
    out = np.empty((flat.shape[0], len(METRICS)))
    seen: dict[bytes, np.ndarray] = {}
    for row, steps in enumerate(flat):
        key = steps.tobytes()
        if key not in seen:
            result = evaluate([None if s < 0 else int(s) for s in steps], outcomes, t_max, dt_mode, metrics_rule)
            seen[key] = np.array([result[m] for m in METRICS], dtype=np.float64)
        out[row] = seen[key]
    return out.reshape(*alarms.shape[:-1], len(METRICS))


def validation_split(failed: np.ndarray, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Disjoint validation and report indices: each outcome class shuffled (seeded) and halved."""
    rng = np.random.default_rng(seed)
    validation: list[int] = []
    report: list[int] = []
    for label in (False, True):
        members = rng.permutation(np.flatnonzero(failed == label))
        half = (members.shape[0] + 1) // 2
        validation.extend(members[:half].tolist())
        report.extend(members[half:].tolist())
    return np.sort(np.array(validation, dtype=int)), np.sort(np.array(report, dtype=int))


@dataclass
class MethodResult:
    """One method at one configuration: metrics per delta ``[tasks, seeds, deltas, 5]`` and their state."""

    method: str
    group: Group
    per_delta: np.ndarray
    infinite: np.ndarray
    """``[tasks, seeds, deltas]``: the configuration's threshold is +inf there (its metrics are NaN)."""
    false_alarms: np.ndarray
    """``[tasks, seeds, deltas]``: false-alarm rate on the held-out ID successes (NaN: none, or +inf)."""
    task_groups: tuple[Group, ...] = ()
    """Per task its own configuration, where a protocol chooses per task (:data:`PER_TASK`; ``group`` is then the
    first task's); empty: ``group`` on every task."""

    def group_of(self, task: int) -> Group:
        """The configuration reported on ``task``."""
        return self.task_groups[task] if self.task_groups else self.group

    @property
    def per_task_choice(self) -> bool:
        """Whether the configuration was chosen per task (:attr:`task_groups`)."""
        return bool(self.task_groups)

    @property
    def values(self) -> np.ndarray:
        """Metrics averaged over the finite deltas, ``[tasks, seeds, 5]``."""
        return delta_mean(self.per_delta)

    def per_task(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean and std over seeds, ``[tasks, 5]`` each."""
        return nanmean(self.values, axis=1), nanstd(self.values, axis=1)

    def average(self) -> tuple[np.ndarray, np.ndarray]:
        """Task average per seed, then mean and std over seeds: ``[5]`` each."""
        per_seed = nanmean(self.values, axis=0)
        return nanmean(per_seed, axis=0), nanstd(per_seed, axis=0)


@dataclass
class ProtocolResult:
    """Selected configurations and their reported metrics under one protocol."""

    protocol: str
    selected: dict[str, MethodResult]
    default: dict[str, MethodResult]
    combine_kind: dict[tuple[str, str], MethodResult]
    selection_twa: dict[str, float] = field(default_factory=dict)
    combinations: dict[tuple[str, str, str], MethodResult] = field(default_factory=dict)
    """Each combination's best window per (combine, kind): ``(name, combine, kind)``."""


def delta_mean(metrics: np.ndarray) -> np.ndarray:
    """Average over the delta axis (the second to last), NaN (+inf threshold) cells left out."""
    return nanmean(metrics, axis=metrics.ndim - 2)


def best_group(groups: Sequence[Group], scores: np.ndarray, allowed: Sequence[int]) -> int:
    """Index in ``allowed`` order of the highest score (first on ties; NaN never wins)."""
    candidates = np.array(list(allowed))
    values = np.where(np.isnan(scores[candidates]), -np.inf, scores[candidates])
    return int(candidates[int(np.argmax(values))])


def selection_twa(selection_metrics: np.ndarray, infinite: np.ndarray) -> np.ndarray:
    """The selection statistic of every configuration ``[groups]``: its TWA averaged over the finite deltas, then
    over the tasks and seeds of ``selection_metrics`` (``[tasks, seeds, groups, deltas, 5]``); NaN (never selected)
    for a configuration with no finite delta on some task and seed of ``infinite`` (``[tasks, seeds, groups,
    deltas]``)."""
    twa = nanmean(delta_mean(selection_metrics)[..., METRICS.index("twa")], axis=(0, 1))
    twa[infinite.all(axis=3).any(axis=(0, 1))] = np.nan  # no finite delta on some task and seed: never selected
    return twa


def selectable(group: Group, select_aggregations: Sequence[str]) -> bool:
    """Whether a protocol may select ``group``: the one configuration of a method that has one, else one of the
    aggregations ``select_aggregations``."""
    fixed = METHODS[group.method].fixed if group.method in METHODS else None
    return fixed is not None or group.aggregation in select_aggregations


def run_protocol(
    protocol: str,
    groups: Sequence[Group],
    selection_metrics: np.ndarray,
    report_metrics: np.ndarray,
    methods: Sequence[str],
    default_window: int,
    default_kind: str,
    select_aggregations: Sequence[str] = ("window", "max"),
    infinite: np.ndarray | None = None,
    held_out: np.ndarray | None = None,
) -> ProtocolResult:
    """Select on ``selection_metrics`` and report ``report_metrics`` (both ``[tasks, seeds, groups, deltas, 5]``).

    ``infinite`` ``[tasks, seeds, groups, deltas]`` marks +inf thresholds (default: none), whose metrics must
    be NaN already; ``held_out`` ``[tasks, seeds, groups, deltas]`` is the false-alarm rate on the held-out
    ID successes (default: NaN).
    """
    shape = report_metrics.shape[:-1]
    infinite = np.zeros(shape, dtype=bool) if infinite is None else infinite
    held_out = np.full(shape, np.nan) if held_out is None else held_out
    twa = selection_twa(selection_metrics, infinite)

    def result(method: str, index: int) -> MethodResult:
        return MethodResult(method, groups[index], report_metrics[:, :, index], infinite[:, :, index],
                            held_out[:, :, index])

    selected: dict[str, MethodResult] = {}
    default: dict[str, MethodResult] = {}
    scores: dict[str, float] = {}
    for method in methods:
        fixed = METHODS[method].fixed if method in METHODS else None
        members = [i for i, g in enumerate(groups) if g.method == method and selectable(g, select_aggregations)]
        if not members:
            continue
        best = best_group(groups, twa, members)
        selected[method] = result(method, best)
        scores[method] = float(twa[best])
        # FIPER's default is AND at w/w; swept as a combination (pooled) its window is written once
        candidates = [groups[members[0]]] if fixed is not None else [
            Group(method, f"{default_window}/{default_window}", default_kind, CombineMode.AND.value),
            Group(method, str(default_window), default_kind, CombineMode.AND.value if method == FIPER else "")]
        wanted = next((g for g in candidates if g in groups), None)
        if wanted is not None:
            default[method] = result(method, list(groups).index(wanted))
    combine_kind: dict[tuple[str, str], MethodResult] = {}
    combined: dict[tuple[str, str, str], MethodResult] = {}
    for method in methods:
        voting = [(i, g) for i, g in enumerate(groups)
                  if g.method == method and g.combine and g.aggregation in select_aggregations]
        for combine in dict.fromkeys(g.combine for _, g in voting):
            for kind in dict.fromkeys(g.kind for _, g in voting):
                members = [i for i, g in voting if g.combine == combine and g.kind == kind]
                if members:
                    best = result(method, best_group(groups, twa, members))
                    if method == FIPER:
                        combine_kind[(combine, kind)] = best
                    else:
                        combined[(method, combine, kind)] = best
    return ProtocolResult(protocol, selected, default, combine_kind, scores, combined)


def run_loto(groups: Sequence[Group], metrics: np.ndarray, methods: Sequence[str],
             select_aggregations: Sequence[str] = ("window", "max"), infinite: np.ndarray | None = None,
             held_out: np.ndarray | None = None) -> ProtocolResult:
    """The leave-one-task-out protocol: for every task ``t``, :func:`run_protocol` selects on the other tasks' rows
    of ``metrics`` (``[tasks, seeds, groups, deltas, 5]``) and reports on row ``t`` (:func:`per_task_protocol`).
    ``selection_twa`` is each method's mean over the tasks of the TWA its choice had on the other tasks.

    ``infinite`` and ``held_out`` as for :func:`run_protocol`. A configuration with no finite delta on some task
    and seed of the others or of ``t`` itself (calibration successes only) is never chosen for ``t``."""
    tasks = metrics.shape[0]
    if tasks < 2:
        raise ValueError(f"the leave-one-task-out protocol needs two tasks or more, got {tasks}")
    return per_task_protocol("loto", groups, metrics, metrics, lambda task: [t for t in range(tasks) if t != task],
                             methods, select_aggregations, infinite, held_out)


def run_clean_task(groups: Sequence[Group], selection_metrics: np.ndarray, report_metrics: np.ndarray,
                   methods: Sequence[str], select_aggregations: Sequence[str] = ("window", "max"),
                   infinite: np.ndarray | None = None, held_out: np.ndarray | None = None) -> ProtocolResult:
    """The clean protocol chosen per task: for every task ``t``, :func:`run_protocol` selects on row ``t`` of
    ``selection_metrics`` (its validation half) and reports on row ``t`` of ``report_metrics`` (its report half)
    (:func:`per_task_protocol`); no other task's labels and none of the report half's enter its choice.
    ``selection_twa`` is each method's mean over the tasks of the TWA its choice had on the validation half.
    ``infinite`` and ``held_out`` as for :func:`run_protocol`."""
    return per_task_protocol("clean-task", groups, selection_metrics, report_metrics, lambda task: [task], methods,
                             select_aggregations, infinite, held_out)


def run_paper_task(groups: Sequence[Group], metrics: np.ndarray, methods: Sequence[str],
                   select_aggregations: Sequence[str] = ("window", "max"), infinite: np.ndarray | None = None,
                   held_out: np.ndarray | None = None) -> ProtocolResult:
    """The paper protocol chosen per task, the per-task ceiling: for every task ``t``, :func:`run_protocol` selects on
    row ``t`` of ``metrics`` (``[tasks, seeds, groups, deltas, 5]``, all its test rollouts) and reports on the same
    row (:func:`per_task_protocol`), so per method and task it reports the highest TWA (mean over seeds of the mean
    over the finite deltas) any of its selectable configurations has there. ``infinite`` and ``held_out`` as for
    :func:`run_protocol`."""
    return per_task_protocol("paper-task", groups, metrics, metrics, lambda task: [task], methods, select_aggregations,
                             infinite, held_out)


def per_task_protocol(name: str, groups: Sequence[Group], selection_metrics: np.ndarray, report_metrics: np.ndarray,
                      rows: Callable[[int], list[int]], methods: Sequence[str], select_aggregations: Sequence[str],
                      infinite: np.ndarray | None, held_out: np.ndarray | None) -> ProtocolResult:
    """A protocol that chooses each task's configuration on its own: for every task ``t``, :func:`run_protocol`
    selects on the ``rows(t)`` rows of ``selection_metrics`` and reports on row ``t`` of ``report_metrics`` (both
    ``[tasks, seeds, groups, deltas, 5]``); the per-task results are joined into one :class:`ProtocolResult` whose
    :class:`MethodResult` carry each task's configuration (:attr:`MethodResult.task_groups`). No fixed default (it
    is the paper protocol's: nothing is selected). A configuration with no finite delta (``infinite``) on some task
    and seed of ``rows(t)`` or of ``t`` itself is never chosen for ``t``."""
    tasks = report_metrics.shape[0]
    shape = report_metrics.shape[:-1]
    infinite = np.zeros(shape, dtype=bool) if infinite is None else infinite
    held_out = np.full(shape, np.nan) if held_out is None else held_out
    folds: list[ProtocolResult] = []
    for task in range(tasks):
        chosen_on = rows(task)
        selection = selection_metrics[chosen_on].copy()
        selection[:, :, infinite[chosen_on].all(axis=3).any(axis=(0, 1))] = np.nan  # never selected
        # no fixed default: window 0 is no configuration
        folds.append(run_protocol(name, groups, selection, report_metrics[[task]], methods, 0, "", select_aggregations,
                                  infinite[[task]], held_out[[task]]))

    def joined(parts: list[MethodResult]) -> MethodResult:
        return MethodResult(parts[0].method, parts[0].group, np.concatenate([p.per_delta for p in parts]),
                            np.concatenate([p.infinite for p in parts]),
                            np.concatenate([p.false_alarms for p in parts]), tuple(p.group for p in parts))

    def per_task(choice: list[dict]) -> dict:
        return {key: joined([fold[key] for fold in choice]) for key in choice[0] if all(key in f for f in choice)}

    scores = {m: float(nanmean(np.array([f.selection_twa.get(m, np.nan) for f in folds]), axis=0))
              for m in folds[0].selection_twa}
    return ProtocolResult(name, per_task([f.selected for f in folds]), {}, per_task([f.combine_kind for f in folds]),
                          scores, per_task([f.combinations for f in folds]))


#: The protocols that choose per task from one subset's metrics of every task (the rows they report on), by name.
ON_ONE_SUBSET: dict[str, Callable[..., ProtocolResult]] = {"loto": run_loto, "paper-task": run_paper_task}
