"""``results.md`` (the paper's Table 1 and Table 2 layouts, and the promise) and ``results.json`` (every number).

Cells are ``mean ± std`` over seeds (just the mean with one seed). As in the paper, a DT is put in
brackets when the TPR or TNR of the same cell is below 0.4, and the best value of every row
(Table 1) or column (Table 2) is bold: highest TWA, Acc, TPR, TNR; lowest DT among DTs not in brackets.

No silent infinities: a cell whose threshold is +inf at every delta reads ``inf (M=12 < 19)`` (``M``
rollouts behind the conformal quantile, fewer than the largest delta needs); a cell averaged over only
some of the deltas (the others +inf) or some of the tasks carries ``‡`` and a line under the table says
which. With the elapsed-time baseline among the methods, every table shows each method's TWA minus the
baseline's (per seed, then mean ± std). The promise table sets the false-alarm rate on the held-out ID
successes beside delta, with its binomial standard error ``sqrt(p (1 - p) / n)``, flagged ``⚠`` when above
``delta + 2 sigma``, and the TPR at that delta. Every protocol's section says which protocol its numbers come from;
under the leave-one-task-out protocol each task's row names the configuration chosen for it. The early-detection
table gives every selected configuration's threshold-free AUROC and q-AUC (:mod:`.early`) per task and pooled over
the tasks; a cell without one reads why (one class empty, or no statistic), it is never averaged away.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, PROMISES, RULE_SUMMARIES, TRANSFER
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import info
from fiper_ros.core.fusion import Combine
from fiper_ros.core.thresholds import GUARANTEED_KINDS, minimum_conformal_set
from fiper_ros.evaluation.auto import AutoOutcome
from fiper_ros.evaluation.early import EarlyDetection
from fiper_ros.evaluation.engine import EvaluationResult
from fiper_ros.evaluation.methods import ELAPSED, METHODS
from fiper_ros.evaluation.protocol import METRICS, PER_TASK, PROTOCOLS, SUBSETS, MethodResult, ProtocolResult, nanmean, nanstd
from fiper_ros.evaluation.sweep import CUMULATIVE, Group

LABELS = {"twa": "TWA ↑", "acc": "Acc. ↑", "dt": "DT ↓", "tpr": "TPR ↑", "tnr": "TNR ↑"}
KIND_LABELS = {"cp_band": "CP band", "cp_constant": "CP constant", "time_varying": "time-var.",
               "cp_scaled": "CP scaled"}
SPLIT_TEXT = {
    "split": "split conformal (the default): score models and the thresholds' per-step shape fitted on one half "
             "of the calibration successes, the conformal quantiles on the other half (Proposition 1 holds)",
    "cross": "cross-fitted (K-fold): every calibration success scored by models fitted without its fold, the "
             "test rollouts by models fitted on all (an approximate guarantee)",
    "same": "same data (the paper's Remark 1): models and thresholds on the same calibration successes "
            "(not covered by Proposition 1)",
}
#: What an OR's column of delta promises (:attr:`~fiper_ros.evaluation.sweep.SweepSettings.or_promise`).
OR_PROMISE_TEXT = {
    ENTRY_PROMISE: "An OR of N thresholds sets each at δ (the paper's; it promises N δ, marked so).",
    DELTA_PROMISE: "An OR of N thresholds sets each at δ/N (--or-promise delta): every configuration, OR included, "
                   "promises δ in the column of δ, so all are compared at equal promise.",
}
POOR = 0.4
PARTIAL = "‡"
#: Where each protocol's numbers come from (the heading of its section).
PROTOCOL_TITLES = {
    "paper": "paper protocol (selection and report on all test rollouts)",
    "clean": "clean protocol (selection on a validation half, report on the disjoint half)",
    "loto": "leave-one-task-out protocol (each task's configuration selected on the other tasks' test rollouts, "
            "reported on its own)",
    "clean-task": "clean protocol chosen per task (each task's configuration selected on its own validation half, "
                  "reported on its disjoint half)",
    "paper-task": "paper protocol chosen per task, the per-task ceiling (each task's configuration selected and "
                  "reported on its own test rollouts: every label read; a bound, not a result)",
}
#: Whose ID successes the promise table counts, per subset a protocol reports on (:data:`SUBSETS`).
HELD_OUT_TEXT = {"all": "all test rollouts'", "report": "the report half's"}
#: How a protocol that chooses per task chose (the sentence under its Table 1).
CHOSEN_TEXT = {
    "loto": "Each task's configuration (per method: window and threshold type) maximises the mean TWA across the other "
            "tasks; the task's own labels are never read (its calibration successes are: a configuration whose "
            "threshold is +inf at every delta there is not chosen).",
    "clean-task": "Each task's configuration (per method: window and threshold type) maximises the TWA on that task's "
                  "validation half alone; no other task's labels and none of its report half enter the choice.",
    "paper-task": "Each task's configuration (per method: window and threshold type) maximises the TWA on the very "
                  "test rollouts it is reported on: no choice made without these labels reports more on the task, "
                  "so a figure here is the ceiling of what the sweep's configurations can reach (those a protocol "
                  "may select: the cumulative ones only with --select-cumulative), not an estimate of what a user "
                  "gets.",
}
#: The protocols reporting on all test rollouts whose best method per task --auto's section shows, with its column.
BEST_ON_ALL = {"loto": "LOTO best (TWA)", "paper-task": "ceiling: paper-task best (TWA)"}
FLAG = "⚠"
TWA = METRICS.index("twa")


def window_text(group: Group) -> str:
    """The window of a configuration as the paper writes it (``"15"``, ``"25/50"``, ``"cumulative"``)."""
    return group.window.replace(CUMULATIVE, "∞") if group.window != CUMULATIVE else "cumulative"


def config_text(group: Group) -> str:
    """E.g. ``"w 25/50, time-var., AND"``."""
    combine = f", {group.combine.upper()}" if group.combine else ""
    return f"w {window_text(group)}, {KIND_LABELS[group.kind]}{combine}"


def middle_delta(deltas: tuple[float, ...]) -> float:
    """The delta a single-delta figure or column shows: 0.05 (the calibration default) when swept."""
    return 0.05 if 0.05 in deltas else deltas[len(deltas) // 2]


def _deltas_text(deltas: list[float]) -> str:
    return ", ".join(f"{d:g}" for d in deltas)


class Cells:
    """Which cells of a run are infinite and how they are written (one per :class:`EvaluationResult`)."""

    def __init__(self, result: EvaluationResult) -> None:
        self.result = result
        self.deltas = list(result.settings.sweep.deltas)
        self.index = {g: i for i, g in enumerate(result.groups)}

    def behind(self, group: Group, task: int) -> int:
        """Rollouts behind ``group``'s conformal quantile on ``task`` (the split fixes it for every seed)."""
        return int(self.result.sweep.conformal[task, 0, self.index[group]])

    def inf_text(self, chosen: MethodResult, task: int) -> str | None:
        """``"inf (M=12 < 19)"`` when every delta of ``task`` is +inf, else ``None``."""
        if not chosen.infinite[task].all():
            return None
        return f"inf (M={self.behind(chosen.group_of(task), task)} < {minimum_conformal_set(max(self.deltas))})"

    def partial_note(self, chosen: MethodResult, task: int) -> str | None:
        """The line explaining a task cell averaged over only its finite deltas, else ``None``."""
        infinite = chosen.infinite[task].any(axis=0)
        if not infinite.any() or infinite.all():
            return None
        skipped = [d for d, bad in zip(self.deltas, infinite) if bad]
        return (f"{self.result.tasks[task]}: averaged over delta "
                f"{_deltas_text([d for d, bad in zip(self.deltas, infinite) if not bad])} only; +inf at delta "
                f"{_deltas_text(skipped)} (M={self.behind(chosen.group_of(task), task)} < "
                f"{minimum_conformal_set(max(skipped))})")

    def average_note(self, chosen: MethodResult) -> str | None:
        """The line explaining a task average that leaves out a task with no finite delta, else ``None``."""
        missing = [task for t, task in enumerate(self.result.tasks) if chosen.infinite[t].all()]
        if not missing:
            return None
        return (f"Average over {len(self.result.tasks) - len(missing)} of {len(self.result.tasks)} tasks "
                f"({', '.join(missing)}: inf)")

    def notes(self, chosen: MethodResult, task: int | None) -> list[str]:
        """The notes of one cell: of ``task``, or of the task average (``None``: every task's and its own)."""
        if task is not None:
            notes = [self.partial_note(chosen, task)]
        else:
            notes = [self.partial_note(chosen, t) for t in range(len(self.result.tasks))] + [self.average_note(chosen)]
        return [n for n in notes if n]


def _cell(mean: float, std: float, seeds: int, bracket: bool) -> str:
    if math.isnan(mean):
        return "–"
    text = f"{mean:.2f}" + (f" ± {std:.2f}" if seeds > 1 else "")
    return f"({text})" if bracket else text


def _signed(mean: float, std: float, seeds: int) -> str:
    if math.isnan(mean):
        return "–"
    return f"{mean:+.2f}" + (f" ± {std:.2f}" if seeds > 1 else "")


def _bold_index(values: list[float], metric: str, eligible: list[bool]) -> int | None:
    candidates = [(v, i) for i, (v, ok) in enumerate(zip(values, eligible)) if ok and not math.isnan(v)]
    if not candidates:
        return None
    return (min(candidates) if metric == "dt" else max(candidates, key=lambda c: (c[0], -c[1])))[1]


def _metric_row(means: np.ndarray, stds: np.ndarray, seeds: int, marks: list[str] | None = None,
                replaced: list[str | None] | None = None) -> dict[str, tuple[list[str], int | None]]:
    """Per metric: formatted cells over the columns and the bold column. ``means [columns, 5]``; ``marks``
    are appended to a column's cells, ``replaced`` (e.g. ``inf (M=12 < 19)``) stands for all of them."""
    columns = means.shape[0]
    marks = marks or [""] * columns
    replaced = replaced or [None] * columns
    tpr, tnr = means[:, METRICS.index("tpr")], means[:, METRICS.index("tnr")]
    poor = [bool(a < POOR or b < POOR) for a, b in zip(tpr, tnr)]
    rows: dict[str, tuple[list[str], int | None]] = {}
    for m, metric in enumerate(METRICS):
        bracket = poor if metric == "dt" else [False] * len(poor)
        cells = [replaced[c] or _cell(float(means[c, m]), float(stds[c, m]), seeds, bracket[c]) + marks[c]
                 for c in range(columns)]
        eligible = [not b and replaced[c] is None for c, b in enumerate(bracket)]
        rows[metric] = (cells, _bold_index([float(v) for v in means[:, m]], metric, eligible))
    return rows


def _emphasise(cells: list[str], bold: int | None) -> list[str]:
    return [f"**{c}**" if i == bold else c for i, c in enumerate(cells)]


def _legend(notes: list[tuple[str, str]]) -> list[str]:
    """``‡`` lines under a table: each note once, with the columns or rows it applies to."""
    grouped: dict[str, list[str]] = {}
    for note, who in notes:
        grouped.setdefault(note, [])
        if who not in grouped[note]:
            grouped[note].append(who)
    return ["", *(f"{PARTIAL} {note}: {', '.join(who)}." for note, who in grouped.items())] if grouped else []


def gain(chosen: MethodResult, floor: MethodResult, task: int | None) -> tuple[float, float]:
    """TWA of ``chosen`` minus the elapsed-time baseline's, per seed (task average per seed for
    ``task=None``): mean and std over seeds."""
    if task is None:
        per_seed = nanmean(chosen.values[..., TWA], axis=0) - nanmean(floor.values[..., TWA], axis=0)
    else:
        per_seed = chosen.values[task, :, TWA] - floor.values[task, :, TWA]
    return float(nanmean(per_seed, axis=0)), float(nanstd(per_seed, axis=0))


def table1(result: EvaluationResult, chosen: dict[str, MethodResult]) -> str:
    """Table 1 / Table 5 layout: tasks x metrics rows, methods as columns, the gain over the elapsed-time
    baseline under each task, notes on infinite thresholds below."""
    cells = Cells(result)
    methods = [m for m in result.settings.columns if m in chosen]
    catalogue = result.settings.catalogue()
    seeds = len(result.settings.seeds)
    floor = chosen.get(ELAPSED)
    header = ["Task", "Metric", *(catalogue[m].label for m in methods)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    per_task_choice = any(chosen[m].per_task_choice for m in methods)
    if not per_task_choice:
        lines.append("| Best w | | " + " | ".join(window_text(chosen[m].group) for m in methods) + " |")
        lines.append("| Best threshold | | " + " | ".join(threshold_text(chosen[m].group) for m in methods) + " |")
    notes: list[tuple[str, str]] = []
    per_task = {m: chosen[m].per_task() for m in methods}
    averages = {m: chosen[m].average() for m in methods}
    blocks: list[tuple[str, int | None]] = [(task, t) for t, task in enumerate(result.tasks)] + [("Average", None)]
    for name, t in blocks:
        if t is None:
            means = np.stack([averages[m][0] for m in methods])
            stds = np.stack([averages[m][1] for m in methods])
            replaced: list[str | None] = [None] * len(methods)
        else:
            means = np.stack([per_task[m][0][t] for m in methods])
            stds = np.stack([per_task[m][1][t] for m in methods])
            replaced = [cells.inf_text(chosen[m], t) for m in methods]
            if per_task_choice:
                lines.append(f"| {name} | chosen | " + " | ".join(config_text(chosen[m].group_of(t)) for m in methods)
                             + " |")
        cell_notes = [cells.notes(chosen[m], t) for m in methods]
        notes += [(n, catalogue[m].label) for m, ns in zip(methods, cell_notes) for n in ns]
        marks = [PARTIAL if ns and r is None else "" for ns, r in zip(cell_notes, replaced)]
        for i, (metric, (row, bold)) in enumerate(_metric_row(means, stds, seeds, marks, replaced).items()):
            named = i == 0 and not (per_task_choice and t is not None)  # else the "chosen" row names the task
            lines.append(f"| {name if named else ''} | {LABELS[metric]} | " + " | ".join(_emphasise(row, bold)) + " |")
        if floor is not None:
            lines.append(f"| | TWA − {METHODS[ELAPSED].label} | " + " | ".join(
                _signed(*gain(chosen[m], floor, t), seeds) for m in methods) + " |")
    return "\n".join(lines + _legend(notes))


def table2(result: EvaluationResult, protocol: ProtocolResult) -> str:
    """Table 2 layout: FIPER's operator x threshold type, task averages (and the gain over the elapsed time)."""
    if not protocol.combine_kind:
        return "_FIPER was not evaluated._"
    return _voting_table(result, protocol, {("", *key): chosen for key, chosen in protocol.combine_kind.items()})


def table3(result: EvaluationResult, protocol: ProtocolResult) -> str:
    """Every combination of several detectors: its best window per combine and normalisation, task averages."""
    if not protocol.combinations:
        return "_No combination of several detectors was evaluated._"
    return _voting_table(result, protocol, protocol.combinations)


def _voting_table(result: EvaluationResult, protocol: ProtocolResult,
                  chosen_by: dict[tuple[str, str, str], MethodResult]) -> str:
    """Rows ``(method, combine, kind)`` (method "" for FIPER's own table): best window, task-average metrics and
    the gain over the elapsed time."""
    keys = list(chosen_by)
    cells = Cells(result)
    catalogue = result.settings.catalogue()
    seeds = len(result.settings.seeds)
    floor = protocol.selected.get(ELAPSED)
    chosen = [chosen_by[k] for k in keys]
    means = np.stack([c.average()[0] for c in chosen])
    stds = np.stack([c.average()[1] for c in chosen])
    cell_notes = [cells.notes(c, None) for c in chosen]
    named = any(method for method, _, _ in keys)
    notes = [(n, f"{catalogue[m].label + ' ' if m else ''}{combine.upper()} {KIND_LABELS[kind]}")
             for (m, combine, kind), ns in zip(keys, cell_notes) for n in ns]
    columns = _metric_row(means, stds, seeds, [PARTIAL if ns else "" for ns in cell_notes])
    extra = [f"TWA − {METHODS[ELAPSED].label}"] if floor is not None else []
    header = [*(["Combination"] if named else []), "Operator", "Threshold", "Best w", *(LABELS[m] for m in METRICS),
              *extra]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row, ((method, combine, kind), c) in enumerate(zip(keys, chosen)):
        values = [f"**{columns[m][0][row]}**" if columns[m][1] == row else columns[m][0][row] for m in METRICS]
        if floor is not None:
            values.append(_signed(*gain(c, floor, None), seeds))
        lead = [catalogue[method].label] if named else []
        lines.append("| " + " | ".join([*lead, combine.upper(), KIND_LABELS[kind], chosen_window(result, c), *values])
                     + " |")
    return "\n".join(lines + _legend(notes))


def threshold_text(group: Group) -> str:
    """E.g. ``"time-var., AND"``."""
    return KIND_LABELS[group.kind] + (f", {group.combine.upper()}" if group.combine else "")


def chosen_window(result: EvaluationResult, chosen: MethodResult) -> str:
    """The window of a configuration, per task where it was chosen per task (``"sorting 5; push_t 8"``)."""
    if not chosen.per_task_choice:
        return window_text(chosen.group)
    return "; ".join(f"{task} {window_text(chosen.group_of(t))}" for t, task in enumerate(result.tasks))


def promised_multiple(chosen: MethodResult, streams: tuple[str, ...], task: int = 0,
                      or_promise: str = ENTRY_PROMISE) -> int:
    """How many deltas a configuration's false alarms are promised to stay under: ``N`` for an OR of ``N``
    thresholds at delta each (the union bound), else 1, and 1 for every configuration of a sweep whose OR thresholds
    are at ``delta / N`` (``or_promise`` ``"delta"``, :attr:`~fiper_ros.evaluation.sweep.SweepSettings.or_promise`;
    docs/method.md, "What each threshold guarantees")."""
    combine = chosen.group_of(task).combine
    if not combine or or_promise == DELTA_PROMISE:
        return 1
    return Combine.parse(combine).promised_multiple(len(streams))


def guarantee_text(chosen: MethodResult, split: str, streams: tuple[str, ...], pooled: bool = False,
                   task: int = 0, or_promise: str = ENTRY_PROMISE) -> str:
    """What a configuration promises about false alarms on new successes (docs/method.md, "What each
    threshold guarantees"): the bound, or why there is none; ``streams`` are the configuration's detectors, ``task``
    the task whose configuration it is where it was chosen per task, ``or_promise`` the sweep's
    (:func:`promised_multiple`). External scores were fitted on what their user knows: the bound then holds only if
    that model saw no calibration rollout."""
    group = chosen.group_of(task)
    if group.kind not in GUARANTEED_KINDS:
        return "none (per-step quantile)"
    multiple = promised_multiple(chosen, streams, task, or_promise)
    bound = "δ"
    if group.combine == CombineMode.OR:
        bound = f"{multiple}δ (OR)" if multiple > 1 else f"δ (OR at δ/{len(streams)} each)"
    bound += " over all tasks (pooled)" if pooled else ""
    if all(not info(s).fitted for s in streams) or split == "split":
        text = f"≤ {bound}"  # nothing we fitted saw the conformal rollouts
    elif split == "cross":
        text = f"≈ {bound} (cross-fitted)"
    else:
        return "not covered (same data)"
    external = [info(s).label for s in streams if info(s).reads == "external"]
    return f"{text} if the model of {', '.join(external)} saw no calibration rollout" if external else text


def _shown_deltas(deltas: list[float]) -> list[float]:
    if len(deltas) <= 3:
        return deltas
    return list(dict.fromkeys([min(deltas), middle_delta(tuple(deltas)), max(deltas)]))


def promise_rows(result: EvaluationResult, chosen: MethodResult, task: int, held_out: str,
                 streams: tuple[str, ...]) -> list[dict[str, Any]]:
    """Per delta: the false-alarm rate on the held-out ID successes (mean over seeds), its binomial
    standard error, the rate the configuration of ``streams`` promises (:func:`promised_multiple` times delta; a
    threshold without a guarantee is held to delta), whether the rate is above it by more than ``2 sigma``, the
    TPR, and whether the threshold is +inf."""
    multiple = promised_multiple(chosen, streams, task, result.settings.sweep.or_promise)
    n = result.sweep.id_successes[held_out][task]
    rows = []
    for d, delta in enumerate(result.settings.sweep.deltas):
        infinite = bool(chosen.infinite[task, :, d].any())
        rate = float(nanmean(chosen.false_alarms[task, :, d], axis=0)) if not infinite else math.nan
        sigma = math.sqrt(rate * (1.0 - rate) / n) if n and not math.isnan(rate) else math.nan
        tpr = float(nanmean(chosen.per_delta[task, :, d, METRICS.index("tpr")], axis=0))
        promised = multiple * delta
        rows.append({"delta": delta, "n": n, "infinite": infinite, "rate": rate, "standard_error": sigma,
                     "promised": promised,
                     "above": bool(rate > promised + 2.0 * sigma) if not math.isnan(sigma) else False, "tpr": tpr})
    return rows


def promise_table(result: EvaluationResult, protocol: ProtocolResult) -> str:
    """Every method's selected configuration: false alarms on held-out ID successes beside delta."""
    cells = Cells(result)
    held_out = SUBSETS[protocol.protocol][1]
    shown = _shown_deltas(cells.deltas)
    floor = protocol.selected.get(ELAPSED)
    extra = [f"TWA − {METHODS[ELAPSED].label}"] if floor is not None else []
    header = ["Method", "Config", "Guarantee", "Task", "n", *(f"FA / TPR at δ = {d:g}" for d in shown),
              "δ with FA > promise + 2σ", *extra]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    split = result.settings.method_settings.split
    seeds = len(result.settings.seeds)
    catalogue = result.settings.catalogue()
    for method, chosen in protocol.selected.items():
        for t, task in enumerate(result.tasks):
            rows = promise_rows(result, chosen, t, held_out, catalogue[method].streams)
            by_delta = {row["delta"]: row for row in rows}
            values = []
            for delta in shown:
                row = by_delta[delta]
                if row["infinite"]:
                    values.append(f"inf (M={cells.behind(chosen.group_of(t), t)} < {minimum_conformal_set(delta)})")
                elif math.isnan(row["rate"]):
                    values.append("–")
                else:
                    values.append(f"{row['rate']:.2f} ± {row['standard_error']:.2f}{' ' + FLAG if row['above'] else ''}"
                                  f" / {row['tpr']:.2f}")
            above = [row["delta"] for row in rows if row["above"]]
            first = t == 0
            own = first or chosen.per_task_choice  # a configuration chosen per task is named on every row
            lines.append("| " + " | ".join([
                catalogue[method].label if first else "", config_text(chosen.group_of(t)) if own else "",
                guarantee_text(chosen, split, catalogue[method].streams, result.settings.pooled, t,
                               result.settings.sweep.or_promise) if own else "",
                task, str(rows[0]["n"]), *values,
                _deltas_text(above) if above else "none",
                *([_signed(*gain(chosen, floor, t), seeds)] if floor is not None else [])]) + " |")
    return "\n".join(lines)


def _area_cell(values: np.ndarray, seeds: int, why: str | None) -> str:
    """An AUROC cell: ``mean ± std`` over seeds, or why there is none (never left blank or averaged away)."""
    if why is not None:
        return why
    return _cell(float(nanmean(values, axis=0)), float(nanstd(values, axis=0)), seeds, False)


def _area_gap(figures: EarlyDetection, task: int | None) -> str | None:
    """Why a task's (``None``: the pooled) AUROC is undefined, else ``None``."""
    if not figures.defined:
        return "n/a (no statistic)"
    failures, successes = figures.classes.sum(axis=0) if task is None else figures.classes[task]
    if failures and successes:
        return None
    return "null (no failures)" if not failures else "null (no successes)"


def early_table(result: EvaluationResult, protocol: ProtocolResult) -> str:
    """Every selected configuration's AUROC / q-AUC per task and pooled over the tasks (mean ± std over seeds)."""
    early = result.early.get(protocol.protocol, {})
    if not early:
        return "_No configuration was selected._"
    catalogue = result.settings.catalogue()
    seeds = len(result.settings.seeds)
    header = ["Method", "Config", *(f"{task} AUROC / q-AUC" for task in result.tasks), "Pooled AUROC / q-AUC"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for method, figures in early.items():
        chosen = protocol.selected[method]
        config = ("chosen per task (Table 1)" if chosen.per_task_choice else config_text(chosen.group))
        cells = []
        for t in range(len(result.tasks)):
            why = _area_gap(figures, t)
            cells.append(why or f"{_area_cell(figures.auroc[t], seeds, None)} / {_area_cell(figures.q_auc[t], seeds, None)}")
        why = _area_gap(figures, None)
        cells.append(why or f"{_area_cell(figures.pooled_auroc, seeds, None)} / "
                            f"{_area_cell(figures.pooled_q_auc, seeds, None)}")
        lines.append("| " + " | ".join([catalogue[method].label, config, *cells]) + " |")
    return "\n".join(lines)


def _infinite_summary(result: EvaluationResult) -> list[str]:
    """One line per task: the rollouts behind each conformal kind's quantiles and the deltas they cannot serve."""
    deltas = list(result.settings.sweep.deltas)
    lines = []
    for t, task in enumerate(result.tasks):
        kinds: dict[int, set[str]] = {}
        for group, behind in zip(result.groups, result.sweep.conformal[t, 0]):
            if group.kind in GUARANTEED_KINDS:
                kinds.setdefault(int(behind), set()).add(group.kind)
        parts = []
        for behind, members in sorted(kinds.items()):
            infinite = [d for d in deltas if minimum_conformal_set(d) > behind]
            tail = f"+inf at delta {_deltas_text(infinite)}" if infinite else "finite at every delta"
            labels = ", ".join(KIND_LABELS[k] for k in GUARANTEED_KINDS if k in members)
            parts.append(f"{labels} over {behind} rollouts: {tail}")
        if parts:
            lines.append(f"- {task}: {'; '.join(parts)}.")
    return lines


def data_text(result: EvaluationResult) -> str:
    """What the run evaluated: per task its calibration successes and test rollouts, and SYNTHETIC where its data
    is (the first line of ``results.md`` and the foot of every figure)."""
    return "; ".join(f"{d.task} ({len(d.calibration_successes)} calibration successes, {len(d.test)} test rollouts"
                     f"{', SYNTHETIC' if any(r.metadata.get('synthetic') for r in d.test) else ''})"
                     for d in result.datasets)


def markdown(result: EvaluationResult, figures: list[str]) -> str:
    """The whole ``results.md``."""
    s = result.settings
    synthetic = any(r.metadata.get("synthetic") for d in result.datasets for r in d.test)
    lines = ["# FIPER evaluation", ""]
    if synthetic:
        lines += ["> **SYNTHETIC DATA** (`fiper_ros.evaluation.synthetic`): these numbers exercise the engine; "
                  "they say nothing about real policies.", ""]
    lines += [
        f"Tasks: {data_text(result)}. Seeds: {', '.join(map(str, s.seeds))}. Profile: {s.method_settings.profile}.",
        f"Calibration: {SPLIT_TEXT[s.method_settings.split]}; the same split of every task and seed for every method.",
        f"Sweep: windows {min(s.sweep.windows)}..{max(s.sweep.windows)}"
        f"{' + cumulative' if s.sweep.cumulative else ''}, 1-delta in "
        f"{{{', '.join(f'{1 - d:.2f}' for d in s.sweep.deltas)}}} (metrics averaged over them), thresholds "
        f"{', '.join(KIND_LABELS[k] for k in s.sweep.kinds)}, FIPER pairs '{s.sweep.pairs}', "
        f"{'/'.join(c.upper() for c in s.sweep.combines)}; {len(result.groups)} configurations per task and seed. "
        f"{OR_PROMISE_TEXT[s.sweep.or_promise]}",
        "DT (each rollout's own length, App. B.4) in brackets: TPR or TNR below 0.4. Bold: best of the row "
        "(Table 1) or column (Table 2).",
    ]
    if ELAPSED in s.methods:
        lines.append(f"{METHODS[ELAPSED].label}: the elapsed-time baseline, alarm after k steps with k the conformal "
                     "quantile of the calibration successes' lengths; 'TWA − Elapsed' is each method's gain over it.")
    summary = _infinite_summary(result)
    if summary:
        lines += ["", "Conformal quantiles (+inf where fewer rollouts than delta needs: those cells are left out of "
                  "every average and selection):", *summary]
    lines.append("")
    for name, protocol in result.protocols.items():
        title, held = PROTOCOL_TITLES[name], HELD_OUT_TEXT[SUBSETS[name][1]]
        chosen = CHOSEN_TEXT.get(name, "Each method's window and threshold type maximise the mean TWA across tasks.")
        lines += [f"## Table 1: failure prediction, {title}", "", chosen, "",
                  table1(result, protocol.selected), "",
                  f"## Table 2: FIPER operator and threshold type, {name} protocol (task average)", "",
                  table2(result, protocol), "",
                  f"## Table 3: combinations of detectors, {name} protocol (task average)", "",
                  "MAX and KTH:K share one conformal factor over the normalised detectors (the promise is δ); AND and "
                  "OR give each detector its own "
                  + ("(OR of N: N δ)." if s.sweep.or_promise == ENTRY_PROMISE else "(OR of N: each at δ/N, promise δ)."),
                  "",
                  table3(result, protocol), "",
                  f"## The promise: false alarms on held-out ID successes, {name} protocol", "",
                  f"FA: the fraction of {held} ID-scenario successes alarmed (mean over seeds) ± its binomial "
                  f"standard error; {FLAG}: above the configuration's promise (δ; "
                  + ("N δ for an OR of N thresholds; " if s.sweep.or_promise == ENTRY_PROMISE else "") + "δ where "
                  "there is no guarantee) + 2σ. TPR: over all failures, at the same δ. Guarantee: "
                  "docs/method.md, 'What each threshold guarantees'.", "",
                  promise_table(result, protocol), "",
                  f"## Early detection (threshold-free), {name} protocol", "",
                  "AUROC: of each rollout's maximum of the configuration's windowed score (a combination's and "
                  "FIPER's: of the combined normalised statistic); q-AUC: of its maximum over the first "
                  f"ceil({s.q_auc:g} T_max) steps (T_max: the task's longest test rollout). Ties count 1/2; mean ± std "
                  "over seeds, on the rollouts this protocol reports on; pooled: every task's rollouts in one AUROC, a "
                  "single detector's raw maxima first put on its task's CP constant scale ((m - mean) / std of the fit "
                  "part's maxima; per task an increasing map). "
                  "Both are threshold-free, so they say nothing about the false-alarm promise (the table above).", "",
                  early_table(result, protocol), ""]
        if name in PER_TASK:
            lines += ["The fixed default configuration selects nothing: it is the paper protocol's.", ""]
        if protocol.default:
            lines += [f"## Fixed default configuration, {name} protocol "
                      f"(w = {s.default_window}, {KIND_LABELS[s.default_kind]}, FIPER AND)", "",
                      table1(result, protocol.default), ""]
    if result.auto is not None:
        lines += [auto_section(result, result.auto), ""]
    if figures:
        lines += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figures] + [""]
    return "\n".join(lines)


def _best_of(result: EvaluationResult, protocol: str, task: int) -> tuple[str, float]:
    """The method with the highest mean TWA on ``task`` under ``protocol`` (the elapsed time aside) and that TWA."""
    best = ("–", math.nan)
    for method, chosen in result.protocols[protocol].selected.items():
        value = float(chosen.per_task()[0][task, TWA])
        if method != ELAPSED and not math.isnan(value) and (math.isnan(best[1]) or value > best[1]):
            best = (result.settings.catalogue()[method].label, value)
    return best


def _elapsed_floor(result: EvaluationResult, auto: AutoOutcome) -> tuple[MethodResult, str] | None:
    """The elapsed time's result that ``--auto``'s gain is taken over, and the subset of test rollouts both are
    measured on: a protocol reporting on all test rollouts (paper, loto) first, else a halved protocol's report half;
    ``None`` without the elapsed time."""
    ranked = sorted(result.protocols.items(), key=lambda item: SUBSETS[item[0]][1] != "all")
    return next(((protocol.selected[ELAPSED], SUBSETS[name][1]) for name, protocol in ranked
                 if ELAPSED in protocol.selected and SUBSETS[name][1] in auto.metrics), None)


def _best_cell(result: EvaluationResult, protocol: str, task: int) -> str:
    """The cell of :func:`_best_of` (empty on the average row, ``task`` past the tasks)."""
    if task >= len(result.tasks):
        return ""
    label, value = _best_of(result, protocol, task)
    return f"{label} ({value:.2f})" if not math.isnan(value) else "–"


def auto_section(result: EvaluationResult, auto: AutoOutcome) -> str:
    """``--auto``'s section: per task the configuration it chose from the calibration successes alone, its metrics
    on all test rollouts, its held-out false alarms at delta 0.05 and, beside it, the elapsed time and the best
    configuration the label-reading protocols chose."""
    seeds = len(result.settings.seeds)
    floor = _elapsed_floor(result, auto)
    mean, std = _auto_rows(auto, "all")
    columns = ["Task", f"chosen (seed {result.settings.seeds[0]}, at δ)", "TWA", "TPR", "TNR", "DT", "FA at that δ",
               "q-AUC (average row: pooled)"]
    columns += [f"TWA − Elapsed{'' if floor[1] == 'all' else ', report half'}"] if floor is not None else []
    on_all = {p: title for p, title in BEST_ON_ALL.items() if p in result.protocols}
    columns += list(on_all.values())
    columns += ["TWA, report half"] if "report" in auto.metrics else []
    # the protocols of two halves: each one's best configuration per task beside --auto's own on the report half
    beside = [p for p in PROTOCOLS if p in result.protocols and SUBSETS[p][1] == "report"]
    columns += [f"{p} best, report half (TWA)" for p in beside]
    rows = ["| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)]
    report = _auto_rows(auto, "report") if "report" in auto.metrics else None
    for t in range(len(result.tasks) + 1):
        name = result.tasks[t] if t < len(result.tasks) else "average"
        shown = auto.shown(t) if t < len(result.tasks) else 0
        chosen = _auto_choice(auto, t, shown) if t < len(result.tasks) else ""
        rate = nanmean(auto.held_out["all"][t, :, shown], axis=0) if t < len(result.tasks) else math.nan
        cells = [name, chosen, *(_cell(float(mean[t, m]), float(std[t, m]), seeds, False)
                                 for m in (METRICS.index(k) for k in ("twa", "tpr", "tnr", "dt"))),
                 "–" if math.isnan(rate) else f"{rate:.2f}", _auto_area(auto, t, seeds)]
        if floor is not None:
            elapsed, subset = floor
            values = auto.values(subset)
            per_seed = values[t, :, TWA] if t < len(result.tasks) else nanmean(values[..., TWA], axis=0)
            base = elapsed.values[t, :, TWA] if t < len(result.tasks) else nanmean(elapsed.values[..., TWA], axis=0)
            cells.append(_signed(float(nanmean(per_seed - base, axis=0)), float(nanstd(per_seed - base, axis=0)),
                                 seeds))
        cells += [_best_cell(result, protocol, t) for protocol in on_all]
        if report is not None:
            cells.append(_cell(float(report[0][t][TWA]), float(report[1][t][TWA]), seeds, False))
        cells += [_best_cell(result, protocol, t) for protocol in beside]
        rows.append("| " + " | ".join(cells) + " |")
    record = auto.records[0][0][0]
    promise = result.settings.promise
    if record["rule"] == TRANSFER:
        priors = "; ".join(f"{task}: {', '.join(auto.records[t][0][0]['prior']['tasks'])}"
                           for t, task in enumerate(result.tasks))
        head = ["## --auto: each task's configuration chosen by a prior of other tasks' labelled rollouts (fiper "
                "calibrate --auto --auto-rule transfer)", "",
                f"Rule {record['rule']} v{record['version']} (docs/method.md, 'The third rule'): "
                f"{RULE_SUMMARIES[record['rule']]}; of the task only its calibration successes are read (which "
                f"detectors they feed, how many are conformal), no label of it. The prior's tasks: {priors}. "
                + f"The promise (--auto-promise {promise}): {PROMISES[promise]}, so its FA column is to be read "
                + ("against δ. " if promise == DELTA_PROMISE else "against δ, or N δ where the choice is such an OR. ")
                + ("Thresholds pooled over the tasks (--pool): each choice is calibrated on every task's successes, "
                   "its promise is over all tasks' successes, not task by task. " if result.settings.pooled else "")
                + "The choice is made at every δ (the prior's rank in brackets); metrics are averaged over the "]
    else:
        head = ["## --auto: each task's configuration chosen from its own calibration successes (fiper calibrate "
                "--auto)", "",
                f"Rule {record['rule']} v{record['version']} (docs/method.md, 'Choosing the configuration from "
                f"successes'): {RULE_SUMMARIES[record['rule']]}; no label and no other task is read. The choice is "
                "made at every δ; metrics are averaged over the "]
    return "\n".join([
        *head[:-1], head[-1] +
        "finite δ on all test rollouts; the choice is shown at the finite δ closest to 0.05, FA: the held-out ID "
        "successes alarmed there, q-AUC: that choice's on all test rollouts (threshold-free; "
        + ("the average row pools every task's rollouts, each under its own choice). "
           if auto.early is not None else "none: some choice is not a configuration of the sweep, which measures "
           "them). ")
        + "The LOTO and clean "
        "columns are the best method those protocols chose with failures (of other tasks, or of the task's "
        "validation half).", "", *rows])


def _auto_area(auto: AutoOutcome, task: int, seeds: int) -> str:
    """The q-AUC cell of ``--auto``'s row ``task`` (past the tasks: pooled over them)."""
    if auto.early is None:
        return "–"
    pooled = task >= auto.early.q_auc.shape[0]
    values = auto.early.pooled_q_auc if pooled else auto.early.q_auc[task]
    return _area_cell(values, seeds, _area_gap(auto.early, None if pooled else task))


def _auto_choice(auto: AutoOutcome, task: int, shown: int) -> str:
    """The choice of a task's first seed at the delta ``shown`` (an index), with its prior rank where it has one."""
    record = auto.records[task][0][shown]
    rank = f"; rank {record['rank']}" if record.get("rank") is not None else ""
    return f"{auto.choices[task][0][shown]} (δ={auto.deltas[shown]:g}{rank})"


def _auto_rows(auto: AutoOutcome, subset: str) -> tuple[np.ndarray, np.ndarray]:
    """Per task and the average: mean and std over seeds of ``subset``'s metrics."""
    values = auto.values(subset)
    both = np.concatenate([values, nanmean(values, axis=0)[None]])
    return nanmean(both, axis=1), nanstd(both, axis=1)


def _auto_json(result: EvaluationResult, auto: AutoOutcome) -> dict[str, Any]:
    """``--auto``'s numbers: per subset and task the metrics, per task every choice and the record at delta 0.05."""
    out: dict[str, Any] = {"deltas": list(auto.deltas), "seconds": auto.seconds, "subsets": {}}
    for subset in auto.metrics:
        mean, std = _auto_rows(auto, subset)
        out["subsets"][subset] = {
            name: {**{m: {"mean": mean[t, i], "std": std[t, i]} for i, m in enumerate(METRICS)},
                   **({"held_out_false_alarms": nanmean(auto.held_out[subset][t], axis=0)}
                      if t < len(result.tasks) else {})}
            for t, name in enumerate([*result.tasks, "average"])}
    out["early_detection"] = (_early_json(auto.early, result.tasks) if auto.early is not None else
                              {"undefined": "some choice is not a configuration of the sweep"})
    out["tasks"] = {task: {"choices": auto.choices[t], "shown_delta": auto.deltas[auto.shown(t)],
                           "record": auto.records[t][0][auto.shown(t)],
                           "infinite_deltas": [d for d, bad in zip(auto.deltas, auto.infinite[t].any(axis=0)) if bad]}
                    for t, task in enumerate(result.tasks)}
    return out


def _clean(value: Any) -> Any:
    if isinstance(value, float):
        return None if math.isnan(value) else value
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return _clean(value.tolist())
    return value


def _config_json(group: Group) -> dict[str, str]:
    return {"window": group.window, "threshold": group.kind, "combine": group.combine}


def _early_json(figures: EarlyDetection, tasks: list[str]) -> dict[str, Any]:
    """AUROC and q-AUC per task and pooled: mean, std and per seed (``null`` where undefined, with the reason)."""

    def area(values: np.ndarray, why: str | None) -> dict[str, Any]:
        return {"mean": float(nanmean(values, axis=0)), "std": float(nanstd(values, axis=0)), "seeds": values,
                **({"undefined": why} if why else {})}

    return {"tasks": {task: {"auroc": area(figures.auroc[t], _area_gap(figures, t)),
                             "q_auc": area(figures.q_auc[t], _area_gap(figures, t)),
                             "failures": int(figures.classes[t, 0]), "successes": int(figures.classes[t, 1])}
                      for t, task in enumerate(tasks)},
            "pooled": {"auroc": area(figures.pooled_auroc, _area_gap(figures, None)),
                       "q_auc": area(figures.pooled_q_auc, _area_gap(figures, None))}}


def _method_json(result: EvaluationResult, chosen: MethodResult, held_out: str, floor: MethodResult | None,
                 early: EarlyDetection | None = None) -> dict[str, Any]:
    cells = Cells(result)
    mean, std = chosen.per_task()
    average_mean, average_std = chosen.average()
    split = result.settings.method_settings.split
    streams = result.settings.catalogue()[chosen.method].streams
    return {
        "config": "per task" if chosen.per_task_choice else _config_json(chosen.group),
        "guarantee": "per task" if chosen.per_task_choice else guarantee_text(
            chosen, split, streams, result.settings.pooled, or_promise=result.settings.sweep.or_promise),
        **({"early_detection": _early_json(early, result.tasks)} if early is not None else {}),
        "tasks": {task: {**({"config": _config_json(chosen.group_of(t)),
                             "guarantee": guarantee_text(chosen, split, streams, result.settings.pooled, t,
                                                         result.settings.sweep.or_promise)}
                            if chosen.per_task_choice else {}),
                         **{m: {"mean": mean[t, i], "std": std[t, i], "seeds": chosen.values[t, :, i]}
                            for i, m in enumerate(METRICS)},
                         "conformal_rollouts": cells.behind(chosen.group_of(t), t),
                         "infinite_deltas": [d for d, bad in zip(cells.deltas, chosen.infinite[t].any(axis=0)) if bad],
                         "held_out_false_alarms": promise_rows(result, chosen, t, held_out, streams),
                         **({"twa_gain_over_elapsed": dict(zip(("mean", "std"), gain(chosen, floor, t)))}
                            if floor is not None else {})}
                  for t, task in enumerate(result.tasks)},
        "average": {**{m: {"mean": average_mean[i], "std": average_std[i]} for i, m in enumerate(METRICS)},
                    **({"twa_gain_over_elapsed": dict(zip(("mean", "std"), gain(chosen, floor, None)))}
                       if floor is not None else {})},
    }


def json_document(result: EvaluationResult) -> dict[str, Any]:
    """Everything: settings, timings, protocol results and the whole sweep (per delta, seed-averaged)."""
    s = result.settings
    protocols = {}
    for name, protocol in result.protocols.items():
        held_out = SUBSETS[name][1]
        floor = protocol.selected.get(ELAPSED)
        early = result.early.get(name, {})

        def entries(chosen: dict[Any, MethodResult], figures: dict[str, EarlyDetection] | None = None) -> dict[str, Any]:
            return {"/".join(k) if isinstance(k, tuple) else k:
                    _method_json(result, r, held_out, floor, (figures or {}).get(k)) for k, r in chosen.items()}

        protocols[name] = {"selected": entries(protocol.selected, early), "selection_twa": protocol.selection_twa,
                           "default": entries(protocol.default),
                           "fiper_combine_threshold": entries(protocol.combine_kind),
                           "combinations": entries(protocol.combinations)}
    seed_mean = nanmean(result.metrics["all"], axis=1)
    deltas = list(s.sweep.deltas)
    infinite = result.sweep.infinite.any(axis=1)  # [tasks, groups, deltas], over seeds
    areas = {name: nanmean(values, axis=values.ndim - 2) for name, values in result.sweep.early.items()}  # seed means
    sweep = [
        {"method": g.method, "window": g.window, "threshold": g.kind, "combine": g.combine,
         "metrics": {task: {m: seed_mean[t, i, :, k] for k, m in enumerate(METRICS)} for t, task in enumerate(result.tasks)},
         "early_detection": {"auroc": {task: areas["auroc"][t, i] for t, task in enumerate(result.tasks)},
                             "q_auc": {task: areas["q_auc"][t, i] for t, task in enumerate(result.tasks)},
                             "pooled_auroc": areas["pooled_auroc"][i], "pooled_q_auc": areas["pooled_q_auc"][i]},
         "infinite_deltas": {task: [d for d, bad in zip(deltas, infinite[t, i]) if bad]
                             for t, task in enumerate(result.tasks) if infinite[t, i].any()}}
        for i, g in enumerate(result.groups)
    ]
    document = {
        "synthetic": any(r.metadata.get("synthetic") for d in result.datasets for r in d.test),
        "tasks": {d.task: {"calibration_successes": len(d.calibration_successes), "test": len(d.test),
                           "test_failures": int(d.failed.sum()),
                           "held_out_id_successes": len(d.held_out_id_successes)} for d in result.datasets},
        "settings": {"methods": list(s.methods), "seeds": list(s.seeds), "profile": s.method_settings.profile,
                     "combinations": {c.name: list(c.detectors) for c in s.combinations},
                     "combination_combines": list(s.combines), "pooled": s.pooled,
                     "windows": list(s.sweep.windows), "cumulative": s.sweep.cumulative, "deltas": list(s.sweep.deltas),
                     "thresholds": list(s.sweep.kinds), "combines": list(s.sweep.combines), "pairs": s.sweep.pairs,
                     "or_promise": s.sweep.or_promise,
                     "protocols": list(s.protocols), "split_seed": s.split_seed, "q_auc": s.q_auc,
                     "calibration_split": s.method_settings.split_settings(),
                     "external_scores": {e.stream: {"file": str(e.path), "sha256": e.sha256}
                                         for e in s.method_settings.external},
                     "default": {"window": s.default_window, "threshold": s.default_kind}},
        "metrics_order": list(METRICS),
        "timings_s": result.timings,
        "score_cache": {"hits": result.cache_hits, "misses": result.cache_misses},
        "protocols": protocols,
        **({"auto": _auto_json(result, result.auto)} if result.auto is not None else {}),
        "sweep": sweep,
    }
    return _clean(document)


def write_reports(result: EvaluationResult, directory: Path, figures: list[str]) -> tuple[Path, Path]:
    """Write ``results.md`` and ``results.json`` into ``directory``."""
    directory.mkdir(parents=True, exist_ok=True)
    md, js = directory / "results.md", directory / "results.json"
    md.write_text(markdown(result, figures))
    js.write_text(json.dumps(json_document(result), separators=(",", ":"), allow_nan=False) + "\n")
    return md, js
