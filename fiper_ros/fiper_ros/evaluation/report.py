"""``results.md`` (the paper's Table 1 and Table 2 layouts) and ``results.json`` (every number).

Cells are ``mean ± std`` over seeds (just the mean with one seed). As in the paper, a DT is put in
brackets when the TPR or TNR of the same cell is below 0.4, and the best value of every row
(Table 1) or column (Table 2) is bold: highest TWA, Acc, TPR, TNR; lowest DT among DTs not in brackets.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from fiper_ros.evaluation.engine import EvaluationResult
from fiper_ros.evaluation.methods import METHODS
from fiper_ros.evaluation.protocol import METRICS, MethodResult, ProtocolResult, nanmean
from fiper_ros.evaluation.sweep import CUMULATIVE, Group

LABELS = {"twa": "TWA ↑", "acc": "Acc. ↑", "dt": "DT ↓", "tpr": "TPR ↑", "tnr": "TNR ↑"}
KIND_LABELS = {"cp_band": "CP band", "cp_constant": "CP constant", "time_varying": "time-var."}
POOR = 0.4


def window_text(group: Group) -> str:
    """The window of a configuration as the paper writes it (``"15"``, ``"25/50"``, ``"cumulative"``)."""
    return group.window.replace(CUMULATIVE, "∞") if group.window != CUMULATIVE else "cumulative"


def config_text(group: Group) -> str:
    """E.g. ``"w 25/50, time-var., AND"``."""
    combine = f", {group.combine.upper()}" if group.combine else ""
    return f"w {window_text(group)}, {KIND_LABELS[group.kind]}{combine}"


def _cell(mean: float, std: float, seeds: int, bracket: bool) -> str:
    if math.isnan(mean):
        return "–"
    text = f"{mean:.2f}" + (f" ± {std:.2f}" if seeds > 1 else "")
    return f"({text})" if bracket else text


def _bold_index(values: list[float], metric: str, eligible: list[bool]) -> int | None:
    candidates = [(v, i) for i, (v, ok) in enumerate(zip(values, eligible)) if ok and not math.isnan(v)]
    if not candidates:
        return None
    return (min(candidates) if metric == "dt" else max(candidates, key=lambda c: (c[0], -c[1])))[1]


def _metric_row(means: np.ndarray, stds: np.ndarray, seeds: int) -> dict[str, tuple[list[str], int | None]]:
    """Per metric: formatted cells over the columns and the bold column. ``means [columns, 5]``."""
    tpr, tnr = means[:, METRICS.index("tpr")], means[:, METRICS.index("tnr")]
    poor = [bool(a < POOR or b < POOR) for a, b in zip(tpr, tnr)]
    rows: dict[str, tuple[list[str], int | None]] = {}
    for m, metric in enumerate(METRICS):
        bracket = poor if metric == "dt" else [False] * len(poor)
        cells = [_cell(float(means[c, m]), float(stds[c, m]), seeds, bracket[c]) for c in range(means.shape[0])]
        eligible = [not b for b in bracket]
        rows[metric] = (cells, _bold_index([float(v) for v in means[:, m]], metric, eligible))
    return rows


def _emphasise(cells: list[str], bold: int | None) -> list[str]:
    return [f"**{c}**" if i == bold else c for i, c in enumerate(cells)]


def table1(result: EvaluationResult, chosen: dict[str, MethodResult]) -> str:
    """Table 1 / Table 5 layout: tasks x metrics rows, methods as columns."""
    methods = [m for m in result.settings.methods if m in chosen]
    seeds = len(result.settings.seeds)
    header = ["Task", "Metric", *(METHODS[m].label for m in methods)]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines.append("| Best w | | " + " | ".join(window_text(chosen[m].group) for m in methods) + " |")
    lines.append("| Best threshold | | " + " | ".join(
        KIND_LABELS[chosen[m].group.kind] + (f", {chosen[m].group.combine.upper()}" if chosen[m].group.combine else "")
        for m in methods) + " |")
    blocks: list[tuple[str, np.ndarray, np.ndarray]] = []
    per_task = {m: chosen[m].per_task() for m in methods}
    for t, task in enumerate(result.tasks):
        blocks.append((task, np.stack([per_task[m][0][t] for m in methods]), np.stack([per_task[m][1][t] for m in methods])))
    averages = {m: chosen[m].average() for m in methods}
    blocks.append(("Average", np.stack([averages[m][0] for m in methods]), np.stack([averages[m][1] for m in methods])))
    for name, means, stds in blocks:
        for i, (metric, (cells, bold)) in enumerate(_metric_row(means, stds, seeds).items()):
            lines.append(f"| {name if i == 0 else ''} | {LABELS[metric]} | " + " | ".join(_emphasise(cells, bold)) + " |")
    return "\n".join(lines)


def table2(result: EvaluationResult, protocol: ProtocolResult) -> str:
    """Table 2 layout: FIPER's operator x threshold type, task averages."""
    keys = list(protocol.combine_kind)
    if not keys:
        return "_FIPER was not evaluated._"
    seeds = len(result.settings.seeds)
    means = np.stack([protocol.combine_kind[k].average()[0] for k in keys])
    stds = np.stack([protocol.combine_kind[k].average()[1] for k in keys])
    columns = _metric_row(means, stds, seeds)
    lines = ["| Operator | Threshold | Best w | " + " | ".join(LABELS[m] for m in METRICS) + " |", "|" + "---|" * 8]
    for row, (combine, kind) in enumerate(keys):
        cells = [f"**{columns[m][0][row]}**" if columns[m][1] == row else columns[m][0][row] for m in METRICS]
        group = protocol.combine_kind[(combine, kind)].group
        lines.append(f"| {combine.upper()} | {KIND_LABELS[kind]} | {window_text(group)} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown(result: EvaluationResult, figures: list[str]) -> str:
    """The whole ``results.md``."""
    s = result.settings
    synthetic = any(r.metadata.get("synthetic") for d in result.datasets for r in d.test)
    lines = ["# FIPER evaluation", ""]
    if synthetic:
        lines += ["> **SYNTHETIC DATA** (`fiper_ros.evaluation.synthetic`): these numbers exercise the engine; "
                  "they say nothing about real policies.", ""]
    lines += [
        f"Tasks: {', '.join(result.tasks)}. Seeds: {', '.join(map(str, s.seeds))}. Profile: {s.method_settings.profile}.",
        f"Sweep: windows {min(s.sweep.windows)}..{max(s.sweep.windows)}"
        f"{' + cumulative' if s.sweep.cumulative else ''}, 1-delta in "
        f"{{{', '.join(f'{1 - d:.2f}' for d in s.sweep.deltas)}}} (metrics averaged over them), thresholds "
        f"{', '.join(KIND_LABELS[k] for k in s.sweep.kinds)}, FIPER pairs '{s.sweep.pairs}', "
        f"{'/'.join(c.upper() for c in s.sweep.combines)}; {len(result.groups)} configurations per task and seed.",
        "DT in brackets: TPR or TNR below 0.4. Bold: best of the row (Table 1) or column (Table 2).", "",
    ]
    for name, protocol in result.protocols.items():
        title = ("paper protocol (selection and report on all test rollouts)" if name == "paper"
                 else "clean protocol (selection on a validation half, report on the disjoint half)")
        lines += [f"## Table 1: failure prediction, {title}", "",
                  "Each method's window and threshold type maximise the mean TWA across tasks.", "",
                  table1(result, protocol.selected), "",
                  f"## Table 2: FIPER operator and threshold type, {name} protocol (task average)", "",
                  table2(result, protocol), ""]
        if protocol.default:
            lines += [f"## Fixed default configuration, {name} protocol "
                      f"(w = {s.default_window}, {KIND_LABELS[s.default_kind]}, FIPER AND)", "",
                      table1(result, protocol.default), ""]
    if figures:
        lines += ["## Figures", ""] + [f"![{Path(f).stem}]({f})" for f in figures] + [""]
    return "\n".join(lines)


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


def _method_json(result: EvaluationResult, chosen: MethodResult) -> dict[str, Any]:
    mean, std = chosen.per_task()
    average_mean, average_std = chosen.average()
    return {
        "config": {"window": chosen.group.window, "threshold": chosen.group.kind, "combine": chosen.group.combine},
        "tasks": {task: {m: {"mean": mean[t, i], "std": std[t, i], "seeds": chosen.values[t, :, i]}
                         for i, m in enumerate(METRICS)} for t, task in enumerate(result.tasks)},
        "average": {m: {"mean": average_mean[i], "std": average_std[i]} for i, m in enumerate(METRICS)},
    }


def json_document(result: EvaluationResult) -> dict[str, Any]:
    """Everything: settings, timings, protocol results and the whole sweep (per delta, seed-averaged)."""
    s = result.settings
    protocols = {}
    for name, protocol in result.protocols.items():
        protocols[name] = {
            "selected": {m: _method_json(result, r) for m, r in protocol.selected.items()},
            "selection_twa": protocol.selection_twa,
            "default": {m: _method_json(result, r) for m, r in protocol.default.items()},
            "fiper_combine_threshold": {f"{c}/{k}": _method_json(result, r) for (c, k), r in protocol.combine_kind.items()},
        }
    seed_mean = nanmean(result.metrics["all"], axis=1)
    sweep = [
        {"method": g.method, "window": g.window, "threshold": g.kind, "combine": g.combine,
         "metrics": {task: {m: seed_mean[t, i, :, k] for k, m in enumerate(METRICS)} for t, task in enumerate(result.tasks)}}
        for i, g in enumerate(result.groups)
    ]
    document = {
        "synthetic": any(r.metadata.get("synthetic") for d in result.datasets for r in d.test),
        "tasks": {d.task: {"calibration_successes": len(d.calibration_successes), "test": len(d.test),
                           "test_failures": int(d.failed.sum())} for d in result.datasets},
        "settings": {"methods": list(s.methods), "seeds": list(s.seeds), "profile": s.method_settings.profile,
                     "windows": list(s.sweep.windows), "cumulative": s.sweep.cumulative, "deltas": list(s.sweep.deltas),
                     "thresholds": list(s.sweep.kinds), "combines": list(s.sweep.combines), "pairs": s.sweep.pairs,
                     "protocols": list(s.protocols), "split_seed": s.split_seed,
                     "default": {"window": s.default_window, "threshold": s.default_kind}},
        "metrics_order": list(METRICS),
        "timings_s": result.timings,
        "score_cache": {"hits": result.cache_hits, "misses": result.cache_misses},
        "protocols": protocols,
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
