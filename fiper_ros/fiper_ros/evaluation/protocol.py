"""Metrics of the sweep and the evaluation protocols (Sec. 5 "Evaluation Protocol", App. B.4, C).

Metrics come from :func:`fiper_ros.core.metrics.evaluate` on the sweep's first-alarm steps (identical
alarm vectors are evaluated once). DT uses each rollout's own length ``T`` in the paper profile
(``t / T``) and ``T_max`` over calibration and test in the reference profile (``t / (T_max - 1)``).

Protocols:

- ``"paper"``: every configuration's metrics are averaged over the deltas; each method's window and
  threshold type (for FIPER also the window pair and AND/OR) is the one with the highest mean TWA
  across tasks (and seeds); that configuration is reported per task on the same test rollouts.
- ``"clean"``: the same selection on a validation half of every task's test rollouts (a seeded split,
  stratified by outcome), reported on the disjoint other half.

A fixed default configuration (window and threshold type given, FIPER ``w/w`` with AND) is reported
too. With several seeds, values are mean and standard deviation over seeds; the task average is taken
per seed first.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fiper_ros.core.metrics import evaluate
from fiper_ros.evaluation.sweep import FIPER, Group

METRICS = ("twa", "acc", "dt", "tpr", "tnr")
PROTOCOLS = ("paper", "clean")


def nanmean(values: np.ndarray, axis: int | tuple[int, ...]) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices stay NaN
        return np.nanmean(values, axis=axis)


def nanstd(values: np.ndarray, axis: int) -> np.ndarray:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return np.nanstd(values, axis=axis)


def alarm_metrics(
    alarms: np.ndarray, failed: np.ndarray, horizons: np.ndarray | int, dt_mode: str, subset: np.ndarray | None = None
) -> np.ndarray:
    """:data:`METRICS` ``[..., 5]`` of first-alarm steps ``[..., N]`` (-1: none) with the core's ``evaluate``."""
    index = np.arange(alarms.shape[-1]) if subset is None else np.asarray(subset)
    flat = alarms[..., index].reshape(-1, index.shape[0])
    outcomes = [bool(f) for f in failed[index]]
    t_max: int | list[int] = horizons if isinstance(horizons, int) else [int(h) for h in horizons[index]]
    out = np.empty((flat.shape[0], len(METRICS)))
    seen: dict[bytes, np.ndarray] = {}
    for row, steps in enumerate(flat):
        key = steps.tobytes()
        if key not in seen:
            result = evaluate([None if s < 0 else int(s) for s in steps], outcomes, t_max, dt_mode)
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
    """One method at one configuration: metrics ``[tasks, seeds, 5]`` (mean over deltas)."""

    method: str
    group: Group
    values: np.ndarray

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


def delta_mean(metrics: np.ndarray) -> np.ndarray:
    """Average over the delta axis: ``[tasks, seeds, groups, deltas, 5]`` -> ``[tasks, seeds, groups, 5]``."""
    return nanmean(metrics, axis=3)


def best_group(groups: Sequence[Group], scores: np.ndarray, allowed: Sequence[int]) -> int:
    """Index in ``allowed`` order of the highest score (first on ties; NaN never wins)."""
    candidates = np.array(list(allowed))
    values = np.where(np.isnan(scores[candidates]), -np.inf, scores[candidates])
    return int(candidates[int(np.argmax(values))])


def run_protocol(
    protocol: str,
    groups: Sequence[Group],
    selection_metrics: np.ndarray,
    report_metrics: np.ndarray,
    methods: Sequence[str],
    default_window: int,
    default_kind: str,
    select_aggregations: Sequence[str] = ("window",),
) -> ProtocolResult:
    """Select on ``selection_metrics`` and report ``report_metrics`` (both ``[tasks, seeds, groups, deltas, 5]``)."""
    selection = delta_mean(selection_metrics)
    report = delta_mean(report_metrics)
    twa = nanmean(selection[..., METRICS.index("twa")], axis=(0, 1))
    selected: dict[str, MethodResult] = {}
    default: dict[str, MethodResult] = {}
    scores: dict[str, float] = {}
    for method in methods:
        members = [i for i, g in enumerate(groups) if g.method == method and g.aggregation in select_aggregations]
        if not members:
            continue
        best = best_group(groups, twa, members)
        selected[method] = MethodResult(method, groups[best], report[:, :, best])
        scores[method] = float(twa[best])
        label = f"{default_window}/{default_window}" if method == FIPER else str(default_window)
        wanted = Group(method, label, default_kind, "and" if method == FIPER else "")
        if wanted in groups:
            index = list(groups).index(wanted)
            default[method] = MethodResult(method, wanted, report[:, :, index])
    combine_kind: dict[tuple[str, str], MethodResult] = {}
    fiper_groups = [(i, g) for i, g in enumerate(groups) if g.method == FIPER and g.aggregation in select_aggregations]
    for combine in dict.fromkeys(g.combine for _, g in fiper_groups):
        for kind in dict.fromkeys(g.kind for _, g in fiper_groups):
            members = [i for i, g in fiper_groups if g.combine == combine and g.kind == kind]
            best = best_group(groups, twa, members)
            combine_kind[(combine, kind)] = MethodResult(FIPER, groups[best], report[:, :, best])
    return ProtocolResult(protocol, selected, default, combine_kind, scores)
