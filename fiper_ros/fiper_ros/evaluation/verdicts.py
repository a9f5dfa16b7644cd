"""How FIPER did on rollouts whose outcome is known: each rollout's verdict, and the closing table of ``fiper
replay`` (live and ``--offline``) and ``fiper launch --summary``: TPR, TNR and the mean detection step, per scenario
when the rollouts name one, and over all.

Failures are positives (Sec. 5, :mod:`fiper_ros.core.metrics`, which counts them): an alarm on a failed rollout
is a true positive, no alarm on it a false negative; no alarm on a successful one a true negative, an alarm a
false positive. The detection step of a true positive is the step of its first alarm, ``DT`` that step over the
rollout's steps (the paper's ``t_i / T``). A rollout without an outcome (no END, or END with OUTCOME_UNKNOWN)
gets no verdict and is left out of the counts, which say so.

:func:`in_sample` tells which rollouts a calibration was fitted on (its ``split`` record names their ids): their
verdicts are in-sample and say nothing about new rollouts.
"""
from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from fiper_ros.core.metrics import evaluate
from fiper_ros.evaluation.results import RolloutResult

#: The outcomes that have a verdict, as :class:`RolloutResult` names them.
FAILURE, SUCCESS = "failure", "success"
#: Scenario names that mean "not known" (a START without one, a bag reader's default).
UNNAMED = ("", "unknown")
#: The row over every rollout.
ALL = "all"
#: (failed, alarmed) -> verdict.
VERDICTS = {(True, True): "detected (true positive)", (True, False): "missed (false negative)",
            (False, False): "no false alarm (true negative)", (False, True): "false alarm (false positive)"}


def verdict(result: RolloutResult) -> str:
    """The verdict on one rollout; ``""`` when its outcome is not known."""
    if result.outcome not in (FAILURE, SUCCESS):
        return ""
    return VERDICTS[(result.outcome == FAILURE, result.first_alarm is not None)]


def rollout_line(result: RolloutResult) -> str:
    """One rollout on one line: its steps, first alarm and outcome, and the verdict."""
    judged = verdict(result)
    return result.summary() + (f": {judged}" if judged else ": no verdict (outcome not known)")


@dataclass(frozen=True)
class Tally:
    """The counts of one row of the table (a scenario, or :data:`ALL`)."""

    scenario: str
    rollouts: int
    """Rollouts with a known outcome."""
    unknown: int
    """Rollouts without one (not counted)."""
    tp: int
    fn: int
    tn: int
    fp: int
    detection_steps: tuple[int, ...]
    """First alarm steps of the true positives."""
    dt: float
    """Mean ``t_i / T`` of the true positives (NaN without one)."""

    @property
    def failures(self) -> int:
        return self.tp + self.fn

    @property
    def successes(self) -> int:
        return self.tn + self.fp

    @property
    def tpr(self) -> float:
        """Failures alarmed, of all failures (NaN without failures)."""
        return self.tp / self.failures if self.failures else math.nan

    @property
    def tnr(self) -> float:
        """Successes not alarmed, of all successes (NaN without successes)."""
        return self.tn / self.successes if self.successes else math.nan

    @property
    def mean_detection_step(self) -> float:
        """Mean first alarm step of the true positives (NaN without one)."""
        return sum(self.detection_steps) / len(self.detection_steps) if self.detection_steps else math.nan

    def to_dict(self) -> dict[str, Any]:
        """JSON form (NaN as ``None``)."""
        def number(value: float) -> float | None:
            return None if math.isnan(value) else value

        return {"scenario": self.scenario, "rollouts": self.rollouts, "unknown_outcome": self.unknown,
                "failures": self.failures, "successes": self.successes, "tp": self.tp, "fn": self.fn, "tn": self.tn,
                "fp": self.fp, "tpr": number(self.tpr), "tnr": number(self.tnr),
                "mean_detection_step": number(self.mean_detection_step), "dt": number(self.dt)}


def _tally(scenario: str, results: Sequence[RolloutResult]) -> Tally:
    known = [r for r in results if r.outcome in (FAILURE, SUCCESS)]
    counts = evaluate([r.first_alarm for r in known], [r.outcome == FAILURE for r in known],
                      [max(r.steps, default=0) + 1 for r in known])
    detected = tuple(r.first_alarm for r in known if r.outcome == FAILURE and r.first_alarm is not None)
    return Tally(scenario, len(known), len(results) - len(known), counts["tp"], counts["fn"], counts["tn"],
                 counts["fp"], detected, counts["dt"])


def tally(results: Iterable[RolloutResult]) -> list[Tally]:
    """One row per named scenario (sorted by name) when any rollout names one, then :data:`ALL`."""
    results = list(results)
    scenarios: dict[str, list[RolloutResult]] = {}
    for result in results:
        scenarios.setdefault(result.scenario, []).append(result)
    named = sorted(name for name in scenarios if name not in UNNAMED)
    rows = [_tally(name, scenarios[name]) for name in named]
    if named and any(name in UNNAMED for name in scenarios):
        rows.append(_tally("(none)", [r for r in results if r.scenario in UNNAMED]))
    return [*rows, _tally(ALL, results)]


def _ratio(part: int, whole: int) -> str:
    return f"{part / whole:.2f} ({part}/{whole})" if whole else "-"


def table(rows: Sequence[Tally]) -> list[str]:
    """The closing table: a heading, one line per row, and what was left out."""
    total = rows[-1]
    lines = [f"verdicts on {total.rollouts} rollouts with a known outcome (failures are positives: an alarm on a "
             "failure is a true positive):",
             f"{'scenario':<16}{'rollouts':>9}{'failures':>9}  {'TPR':<14}{'successes':>9}  {'TNR':<14}"
             "mean detection step"]
    for row in rows:
        mean = "-" if not row.detection_steps else f"{row.mean_detection_step:.1f} (DT {row.dt:.2f})"
        lines.append(f"{row.scenario:<16}{row.rollouts:>9}{row.failures:>9}  {_ratio(row.tp, row.failures):<14}"
                     f"{row.successes:>9}  {_ratio(row.tn, row.successes):<14}{mean}")
    if total.unknown:
        lines.append(f"{total.unknown} rollout(s) without an outcome (no END, or END with OUTCOME_UNKNOWN): "
                     "not counted")
    return lines


def in_sample(split: Mapping[str, Any], rollout_ids: Iterable[int]) -> list[int]:
    """The rollouts among ``rollout_ids`` that the calibration's ``split`` record names (fitted on: score models
    or thresholds), sorted; empty for a calibration that does not record them (written before its split existed)."""
    named = {str(i) for part in ("fit", "conformal") for i in split.get(part, ())}
    named |= {str(i) for fold in split.get("folds", ()) for i in fold}
    return sorted(i for i in set(rollout_ids) if str(i) in named)


def in_sample_warning(split: Mapping[str, Any], rollout_ids: Iterable[int]) -> str:
    """The warning when rollouts of ``rollout_ids`` are the calibration's own; ``""`` when none is."""
    ids = list(rollout_ids)
    own = in_sample(split, ids)
    if not own:
        return ""
    shown = ", ".join(map(str, own[:5])) + (", ..." if len(own) > 5 else "")
    return (f"warning: {len(own)} of the {len(set(ids))} rollouts are the calibration's own (rollout {shown}): it "
            "was fitted on them, so their verdicts are in-sample and say nothing about new rollouts; judge FIPER on "
            "rollouts it was not calibrated on")
