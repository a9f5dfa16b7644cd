"""Priors of the ``transfer`` rule (:mod:`fiper_ros.core.transfer`) from a run's labelled metrics, and ``fiper
evaluate --auto --auto-rule transfer``.

:func:`ranked_prior` ranks every configuration of the sweep that a calibration can declare and that keeps a promise
(:func:`entry_of`; a configuration with no finite delta on some task and seed is left out) by one of the statistics
:data:`~fiper_ros.core.transfer.STATISTICS` (:func:`prior_order`; ``mean``, the default, is the one the paper and
leave-one-task-out protocols select with, :func:`~fiper_ros.evaluation.protocol.selection_twa`), computed on all
test rollouts over all methods and combinations at once, and keeps the best ``top`` (each configuration once: the
first of the methods that sweep it). ``fiper evaluate --write-prior`` writes the one of every task of the run.

:func:`transfer_evaluation`: for every task ``T`` the prior is the one of the other tasks' rows of the run's
metrics (exactly the leave-one-task-out selection, over all methods at once), so no label of ``T`` enters it, or a
prior file given for every task. At every delta the rule (:func:`fiper_ros.core.transfer.choose_from_prior`) picks
its entry from what ``T``'s data feed and how many conformal successes ``T`` has, and the entry is calibrated on
``T``'s calibration successes as the sweep calibrates it (its shapes from the fit part's curves of the run's score
streams, its conformal quantile from the conformal part's) and judged on ``T``'s test rollouts. With the promise
``delta`` (:data:`~fiper_ros.core.auto.PROMISES`) an OR entry of ``N`` thresholds is calibrated at ``delta / N``
each and the priors rank every entry at equal promise (:func:`at_equal_promise`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

import fiper_ros
from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, RULES, TRANSFER, AutoSettings
from fiper_ros.core.calibration.auto import finite_at_delta, transfer_settings
from fiper_ros.core.detectors import declarable, info
from fiper_ros.core.equalisation import DEFAULT_LEVEL
from fiper_ros.core.thresholds import GUARANTEED_KINDS
from fiper_ros.core.transfer import STATISTICS, Prior, PriorEntry, PriorError, choose_from_prior
from fiper_ros.evaluation.auto import AutoOutcome, calibrated_alarms, candidate_streams, evaluate_choices
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.methods import Combination, MethodSettings, method_of
from fiper_ros.evaluation.protocol import METRICS, delta_mean, nanmean, selectable, selection_twa
from fiper_ros.evaluation.sweep import CUMULATIVE, MAX_POOL, Group

#: How many of a method's best configurations the ``family`` statistic averages to rank the methods.
FAMILY_TOP = 10
#: How many steps of the sweep's window grid, each way, the ``smooth`` statistic's neighbours reach.
SMOOTH_STEPS = 2


def selection(statistic: str, promise: str, swept: str = ENTRY_PROMISE) -> dict[str, str]:
    """How a prior's entries are ranked, as its file says (``statistic``: a name of
    :data:`~fiper_ros.core.transfer.STATISTICS`; ``promise``: of :data:`~fiper_ros.core.auto.PROMISES`, the promise
    its figures are at, :func:`at_equal_promise`; ``swept``: the sweep's
    :attr:`~fiper_ros.evaluation.sweep.SweepSettings.or_promise`)."""
    twa = ("each configuration's TWA on a task averaged over its finite deltas and the seeds; configurations with no "
           "finite delta on some task and seed left out")
    if promise == DELTA_PROMISE and swept == DELTA_PROMISE:
        twa += "; an OR of N thresholds swept at delta / N each (every entry's figures at the promise delta)"
    elif promise == DELTA_PROMISE:
        twa += ("; an OR of N thresholds only over the deltas d whose N d is a delta of the run, its figures at "
                "promise N d (every entry's at the promises of the run's deltas)")
    return {"subset": "all test rollouts", "statistic": statistic, "ranks_by": STATISTICS[statistic], "twa": twa,
            "promise": promise,
            "kept": "guaranteed thresholds (CP constant, band, scaled); detectors a calibration declares; one "
                    "aggregation for all detectors; OR with its promise N delta"}


def at_equal_promise(groups: Sequence[Group], members: Mapping[str, Member], metrics: np.ndarray,
                     infinite: np.ndarray, deltas: Sequence[float]) -> tuple[np.ndarray, np.ndarray]:
    """``metrics`` ``[tasks, seeds, groups, deltas, 5]`` and ``infinite`` ``[tasks, seeds, groups, deltas]`` with
    every OR of ``N`` thresholds kept only at the deltas ``d`` whose ``N d`` is one of ``deltas`` (its figures there
    are those of promise ``N d``, a promise the other configurations are measured at); its other deltas NaN and
    +inf, as a threshold that never alarms is left out of the averages. Copies; the inputs are not changed."""
    metrics, infinite = metrics.copy(), infinite.copy()
    grid = np.asarray(deltas, dtype=np.float64)
    for i, group in enumerate(groups):
        entry = entry_of(group, members[group.method])
        multiple = entry.promised_multiple if entry is not None else 1
        if multiple > 1:
            kept = np.isclose(multiple * grid[:, None], grid[None, :], rtol=1e-9, atol=1e-12).any(axis=1)
            metrics[:, :, i, ~kept] = np.nan
            infinite[:, :, i, ~kept] = True
    return metrics, infinite


def rank_percentiles(values: np.ndarray) -> np.ndarray:
    """Each finite value's rank percentile among the finite ``values`` (1-D): 0 the smallest, 1 the largest, ties
    sharing their mean rank, 1 for a single one; NaN stays NaN."""
    out = np.full(values.shape, np.nan)
    finite = np.isfinite(values)
    if finite.sum() == 1:
        out[finite] = 1.0
    elif finite.any():
        ordered = np.sort(values[finite])
        below = np.searchsorted(ordered, values[finite], side="left")
        equal = np.searchsorted(ordered, values[finite], side="right") - below
        out[finite] = (below + (equal - 1) / 2) / (ordered.size - 1)
    return out


def _neighbours(groups: Sequence[Group], candidates: Sequence[int]) -> dict[int, list[int]]:
    """Per candidate, the candidates of the same method, kind, combine and aggregation whose every window is within
    :data:`SMOOTH_STEPS` steps of its own on the window grid of those configurations (itself included)."""
    buckets: dict[tuple, list[int]] = {}
    for i in candidates:
        g = groups[i]
        shape = tuple(_window(label)[0] for label in g.window.split("/"))
        buckets.setdefault((g.method, g.kind, g.combine, shape), []).append(i)
    out: dict[int, list[int]] = {}
    for members in buckets.values():
        windows = np.array([[w or 0 for _, w in map(_window, groups[i].window.split("/"))] for i in members])
        steps = np.column_stack([np.searchsorted(np.unique(column), column) for column in windows.T])
        near = np.abs(steps[:, None, :] - steps[None, :, :]).max(axis=2) <= SMOOTH_STEPS
        for row, i in enumerate(members):
            out[i] = [members[j] for j in np.flatnonzero(near[row])]
    return out


def prior_order(groups: Sequence[Group], per_task: np.ndarray, mean: np.ndarray, candidates: Sequence[int],
                statistic: str) -> list[int]:
    """``candidates`` (indices of ``groups``), best first by ``statistic`` (:data:`~fiper_ros.core.transfer.STATISTICS`)
    on ``per_task`` (``[tasks, groups]``: each configuration's TWA per task; NaN where a task's TWA is undefined, e.g.
    a task without failures, which the statistics leave out) and ``mean`` (``[groups]``: the mean TWA over the tasks
    and seeds, :func:`~fiper_ros.evaluation.protocol.selection_twa`, finite for every candidate); ties by ``mean``,
    then the sweep's order."""
    if statistic not in STATISTICS:
        raise PriorError(f"prior statistic {statistic!r}; expected one of {', '.join(STATISTICS)}")
    cands = np.asarray(candidates, dtype=np.int64)
    values = per_task[:, cands]  # [tasks, candidates]
    means = mean[cands]
    if statistic == "mean":
        score = means
    elif statistic == "worst":
        score = np.nanmin(values, axis=0)
    elif statistic == "rank":
        score = nanmean(np.array([rank_percentiles(row) for row in values]), axis=0)
    elif statistic == "smooth":
        near = _neighbours(groups, cands.tolist())
        column = {int(i): n for n, i in enumerate(cands)}
        score = np.array([nanmean(values[:, [column[j] for j in near[int(i)]]], axis=(0, 1)) for i in cands])
    else:  # family
        best: dict[str, list[float]] = {}
        for i, value in zip(cands, means):
            best.setdefault(groups[i].method, []).append(float(value))
        strength = {m: float(np.mean(sorted(v, reverse=True)[:FAMILY_TOP])) for m, v in best.items()}
        families = sorted(strength, key=lambda m: (-strength[m], m))
        score = np.array([-families.index(groups[i].method) for i in cands], dtype=np.float64)
    return [int(cands[n]) for n in sorted(range(cands.size), key=lambda n: (-score[n], -means[n], cands[n]))]


@dataclass(frozen=True)
class Member:
    """What a method or combination of the run sweeps: its detectors and its joint combines' equalisation."""

    detectors: tuple[str, ...]
    equalise: str = "none"
    level: float = DEFAULT_LEVEL


def members_of(methods: Sequence[str], combinations: Sequence[Combination]) -> dict[str, Member]:
    """Every method's and combination's :class:`Member`, by name."""
    out = {m: Member(method_of(m).streams) for m in methods}
    out.update({c.name: Member(c.detectors, c.equalise, c.level) for c in combinations})
    return out


def _window(label: str) -> tuple[str, int | None]:
    """A sweep window label as ``(aggregation, window)``: ``"5"`` a window sum, ``"max5"`` max-pooled, ``"cum"``."""
    if label == CUMULATIVE:
        return "cumulative", None
    if label.startswith(MAX_POOL):
        return "max", int(label.removeprefix(MAX_POOL))
    return "window", int(label)


def entry_of(group: Group, member: Member) -> PriorEntry | None:
    """The prior entry of a swept configuration, or ``None`` if no calibration can declare it or it keeps no promise
    (a time-varying threshold, a baseline's or external detector, two detectors of different aggregations)."""
    if group.kind not in GUARANTEED_KINDS or not all(declarable(d) for d in member.detectors):
        return None
    windowed = [d for d in member.detectors if info(d).aggregation is None]
    parts = [_window(label) for label in group.window.split("/")]
    if len(parts) > 1 and len(parts) != len(windowed):
        return None
    if len({aggregation for aggregation, _ in parts}) > 1:
        return None  # e.g. FIPER's cum/5: a calibration has one aggregation
    aggregation = parts[0][0] if windowed else "cumulative"
    windows = {} if aggregation == "cumulative" else \
        {d: parts[i if len(parts) > 1 else 0][1] for i, d in enumerate(windowed)}
    equalise = member.equalise if group.combine and member.equalise != "none" else "none"
    return PriorEntry(member.detectors, aggregation, windows, group.kind, group.combine, equalise, member.level,
                      group.method)


def entry_of_choice(record: Mapping[str, Any]) -> PriorEntry | None:
    """The configuration an ``--auto`` record (any rule's) chose, as a prior entry (its key is what a calibration
    declares); ``None`` where no configuration could be chosen."""
    chosen = record.get("chosen")
    if chosen is None:
        return None
    if record["rule"] == TRANSFER:
        return PriorEntry.from_dict(chosen)
    detectors = tuple(chosen["detectors"])
    windowed = [d for d in detectors if info(d).aggregation is None]
    try:
        return PriorEntry(detectors, "window" if windowed else "cumulative", dict.fromkeys(windowed, chosen["window"]),
                          chosen["kind"], chosen["combine"] if len(detectors) > 1 else "")
    except PriorError:  # a configuration no prior could hold (and so no sweep entry is)
        return None


def chosen_groups(auto: AutoOutcome, groups: Sequence[Group], members: Mapping[str, Member], seeds: Sequence[int]
                  ) -> dict[int, list[Group]] | None:
    """Per seed, each task's configuration of the sweep that ``--auto`` chose for it at the delta its choice is shown
    at (:meth:`AutoOutcome.shown`; the first of the sweep's configurations with the same key); ``None`` when some
    choice is not a configuration of the sweep, or there was none."""
    index: dict[tuple, int] = {}
    for i, group in enumerate(groups):
        entry = entry_of(group, members[group.method])
        if entry is not None:
            index.setdefault(entry.key(), i)
    out: dict[int, list[Group]] = {}
    for s, seed in enumerate(seeds):
        row = []
        for t in range(len(auto.records)):
            entry = entry_of_choice(auto.records[t][s][auto.shown(t)])
            found = None if entry is None else index.get(entry.key())
            if found is None:
                return None
            row.append(groups[found])
        out[seed] = row
    return out


def ranked_prior(groups: Sequence[Group], metrics: np.ndarray, infinite: np.ndarray, tasks: Sequence[str],
                 members: Mapping[str, Member], select_aggregations: Sequence[str], top: int,
                 header: Mapping[str, Any], statistic: str, promise: str, swept: str = ENTRY_PROMISE) -> Prior:
    """The prior of ``tasks`` (module docstring) from their rows of ``metrics`` ``[tasks, seeds, groups, deltas, 5]``
    (all test rollouts) and ``infinite`` ``[tasks, seeds, groups, deltas]``, ranked by ``statistic``
    (:func:`prior_order`) at ``promise`` (:data:`~fiper_ros.core.auto.PROMISES`; ``delta``: every entry's figures at
    the promises of the header's deltas, :func:`at_equal_promise`, unless the sweep already set an OR's thresholds at
    ``delta / N``: ``swept``, its :attr:`~fiper_ros.evaluation.sweep.SweepSettings.or_promise`); ``header``: the
    :class:`Prior`'s other fields (seeds, deltas, calibration, made_from, command, version)."""
    if top < 1:
        raise ValueError(f"a prior keeps at least one entry, got top {top}")
    if promise != DELTA_PROMISE and swept == DELTA_PROMISE:
        raise ValueError(f"a prior at promise {promise!r} needs each OR's figures at delta each, the sweep's are at "
                         "delta / N")
    if promise == DELTA_PROMISE and swept != DELTA_PROMISE:
        metrics, infinite = at_equal_promise(groups, members, metrics, infinite, header["deltas"])
    twa = selection_twa(metrics, infinite)
    values = delta_mean(metrics)  # [tasks, seeds, groups, 5]
    per_task = nanmean(values[..., METRICS.index("twa")], axis=1)  # [tasks, groups]
    means = {m: nanmean(values[..., METRICS.index(m)], axis=(0, 1)) for m in ("tpr", "tnr")}
    declared = {i: entry for i, g in enumerate(groups) if selectable(g, select_aggregations) and not np.isnan(twa[i])
                and (entry := entry_of(g, members[g.method])) is not None}
    entries: dict[tuple, PriorEntry] = {}
    for i in prior_order(groups, per_task, twa, list(declared), statistic) if declared else []:
        entry = declared[i]
        if entry.key() in entries:
            continue
        entries[entry.key()] = replace(entry, twa=float(twa[i]), tpr=float(means["tpr"][i]),
                                       tnr=float(means["tnr"][i]),
                                       per_task={t: float(per_task[n, i]) for n, t in enumerate(tasks)})
        if len(entries) == top:
            break
    if not entries:
        raise PriorError(f"no configuration of the run on {', '.join(tasks)} can be a prior entry (a guaranteed "
                         "threshold, detectors a calibration declares, a finite delta on every task)")
    return Prior(tuple(entries.values()), tuple(tasks), selection=selection(statistic, promise, swept), **header)


def prior_header(datasets: Sequence[Dataset], method_settings: MethodSettings, seeds: Sequence[int],
                 deltas: Sequence[float], command: str, pooled: bool = False) -> dict[str, Any]:
    """The header of a prior made from the labelled test rollouts of ``datasets`` (``pooled``: measured with thresholds
    pooled over them, said in its ``calibration``)."""
    made = ", ".join(f"{d.task} ({len(d.test)} test rollouts, {int(np.sum(d.failed))} failures)" for d in datasets)
    return {"seeds": tuple(seeds), "deltas": tuple(deltas),
            "calibration": {"profile": method_settings.profile, **method_settings.split_settings(),
                            **({"pooled": True} if pooled else {})},
            "made_from": f"the labelled test rollouts of {made} in one fiper evaluate run", "command": command,
            "version": fiper_ros.__version__}


def loto_priors(datasets: Sequence[Dataset], groups: Sequence[Group], metrics: np.ndarray, infinite: np.ndarray,
                members: Mapping[str, Member], method_settings: MethodSettings, seeds: Sequence[int],
                deltas: Sequence[float], select_aggregations: Sequence[str], top: int,
                statistic: str, promise: str, pooled: bool = False, swept: str = ENTRY_PROMISE) -> list[Prior]:
    """Per task ``T``, the prior of the other tasks' rows of ``metrics`` (all test rollouts, ``[tasks, seeds, groups,
    deltas, 5]``) and ``infinite`` ranked by ``statistic`` at ``promise`` (:func:`ranked_prior`, ``swept`` the sweep's
    OR promise): a leave-one-task-out selection over all methods at once; no row of ``T`` enters it."""
    if len(datasets) < 2:
        raise ValueError(f"a prior of other tasks needs two tasks or more, got {len(datasets)}")
    names = [d.task for d in datasets]
    priors = []
    for t in range(len(datasets)):
        others = [n for n in range(len(datasets)) if n != t]
        header = prior_header([datasets[n] for n in others], method_settings, seeds, deltas,
                              f"leave-one-task-out prior of this run for {names[t]}", pooled)
        priors.append(ranked_prior(groups, metrics[others], infinite[others], [names[n] for n in others], members,
                                   select_aggregations, top, header, statistic, promise, swept))
    return priors


def transfer_evaluation(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
                        streams: Sequence[str], groups: Sequence[Group], metrics: np.ndarray, infinite: np.ndarray,
                        members: Mapping[str, Member], method_settings: MethodSettings, seeds: Sequence[int],
                        deltas: Sequence[float], auto: AutoSettings, subsets: dict[str, list[np.ndarray | None]],
                        held_out: dict[str, list[np.ndarray]], select_aggregations: Sequence[str], top: int,
                        statistic: str, prior: Prior | None = None, progress: bool = True,
                        pooled: bool = False, swept: str = ENTRY_PROMISE) -> AutoOutcome:
    """``--auto --auto-rule transfer`` on every task and seed (module docstring): per task the prior of the other
    tasks' rows of ``metrics`` (all test rollouts, ``[tasks, seeds, groups, deltas, 5]``) and ``infinite`` ranked by
    ``statistic``, or ``prior`` for every task; metrics on ``subsets`` and false alarms on ``held_out`` as
    :func:`~fiper_ros.evaluation.auto.evaluate_choices` takes them. ``pooled``: the chosen entry's thresholds are
    pooled over every task (one conformal quantile of every task's normalised conformal curves, as the sweep's
    pooled ones; ``metrics`` are then the pooled sweep's), so the conformal successes of every task count toward a
    finite threshold; its promise is over all tasks' successes. ``swept``: the sweep's OR promise
    (:func:`ranked_prior`)."""
    pool = candidate_streams(streams)
    priors = [prior] * len(datasets) if prior is not None else \
        loto_priors(datasets, groups, metrics, infinite, members, method_settings, seeds, deltas, select_aggregations,
                    top, statistic, auto.promise, pooled, swept)

    def choices(t: int, dataset: Dataset, seed: int) -> tuple[list[str], list[dict[str, Any]], np.ndarray,
                                                              np.ndarray]:
        base = replace(method_settings.calibration_settings(seed), pooled=pooled)
        together = datasets if pooled else [dataset]  # the tasks its thresholds are calibrated on
        successes = [len(d.calibration_successes) for d in together]
        alarms = np.full((len(deltas), len(dataset.test)), -1, dtype=np.int64)
        bad = np.zeros(len(deltas), dtype=bool)
        labels, records = [], []
        for k, delta in enumerate(deltas):
            at = replace(base, delta=delta)
            try:
                choice = choose_from_prior(priors[t], pool, lambda e: finite_at_delta(e, successes, at, auto.promise),
                                           auto, delta)
            except PriorError as error:
                bad[k] = True
                labels.append("none")
                records.append({"rule": TRANSFER, "version": RULES[TRANSFER], "delta": delta,
                                "prior": {"content_hash": priors[t].content_hash, "tasks": list(priors[t].tasks)},
                                "rank": None, "chosen": None, "why": str(error)})
                continue
            settings = transfer_settings(at, choice)
            fitted = {d.task: ({x: scores[(d.task, seed)][x].fit for x in settings.detectors}, scores[(d.task, seed)])
                      for d in together}
            alarms[k], bad[k] = calibrated_alarms(dataset, fitted, settings)
            labels.append(choice.label())
            records.append(choice.record(top=5))
        return labels, records, alarms, bad

    return evaluate_choices(datasets, method_settings, seeds, deltas, subsets, held_out, choices, progress)
