"""The third rule of ``--auto``, ``transfer``: the configuration chosen by labelled rollouts of other tasks.

A user calibrating a new task has no failure of it, but others have labelled failures of other tasks. A **prior**
(:class:`Prior`) is what those tasks say: a ranked list of configurations (:class:`PriorEntry`: detectors, their
windows and aggregation, the threshold kind, the combine and the equalisation, everything a calibration declares),
each with the mean TWA it had on the prior's tasks' labelled test rollouts (App. B.4) and per task. Only
configurations that keep a promise are entries: a guaranteed threshold kind (CP constant, CP band, CP scaled; never
a time-varying one), one detector or a combine with one conformal factor (``max``, ``kth:K``), AND (``delta``), or
OR with its promise stated as a calibration states it (``N delta`` for N thresholds, the union bound). ``fiper
evaluate --write-prior`` writes one from a run's labelled metrics (:mod:`fiper_ros.evaluation.transfer`).

**The rule** (:func:`choose_from_prior`) reads the prior and, of the task being calibrated, only what its
successes can feed and how many conformal successes it has: the highest-ranked entry whose detectors the successes
can feed and whose threshold is finite at the calibration's delta with its conformal successes wins. No rollout
of the task is scored for the choice, and no label of it exists to be read.

**The promise** (:data:`~fiper_ros.core.auto.PROMISES`, ``--auto-promise``): by default (``delta``) every choice
promises the calibration's delta: an OR entry's ``N`` thresholds are calibrated at ``delta / N`` each
(:func:`threshold_delta`), so its threshold needs ``N`` times the conformal successes, and a prior made for it (its
``selection.promise``) ranks each OR entry by its figures at the promises of the other entries
(:mod:`fiper_ros.evaluation.transfer`); with ``entry`` an entry keeps its own (``N delta`` for an OR of ``N``).

**Why it should transfer**: what separates configurations that keep the same promise is how early failures cross
their threshold, which only labelled failures show; detectors, windows and threshold kinds that caught the
failures of several other tasks of the same policy family early and rarely alarmed on their successes are the
best guess for a new task's failures, which nothing of the new task can measure. Its blind spot: the prior's
tasks may not resemble the user's (another robot, another policy, failures of another kind); the prior says which
tasks it was learned on, and the calibration stores the prior's content hash and the entry's rank.

A prior file (YAML) has a format version, the tasks, seeds and deltas it was learned on, the selection statistic
(one of :data:`STATISTICS`; a file naming another is refused), the command that made it and a SHA-256 content hash over everything else; a modified file is refused.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, PROMISES, RULES, TRANSFER, AutoError, AutoSettings
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import check_declared, in_fusion_order
from fiper_ros.core.equalisation import DEFAULT_LEVEL, check_equalisation
from fiper_ros.core.errors import CoreError
from fiper_ros.core.fusion import Combine
from fiper_ros.core.thresholds import GUARANTEED_KINDS

#: The prior file format this code writes and reads.
PRIOR_FORMAT = 1
#: What a prior file says it is (its ``kind``).
PRIOR_KIND = "fiper-transfer-prior"
#: Entries a prior keeps by default (``fiper evaluate --prior-top``).
PRIOR_TOP = 200
#: The statistics a prior may rank its entries by (its ``selection.statistic``), each with what it ranks by; every
#: one is computed from the prior's tasks' labelled metrics (``fiper evaluate --prior-statistic``,
#: :mod:`fiper_ros.evaluation.transfer`), each configuration's TWA on a task being averaged over its finite deltas
#: and the seeds.
STATISTICS = {
    "mean": "the mean over the tasks of each configuration's TWA (the paper and leave-one-task-out protocols' "
            "selection statistic)",
    "worst": "the worst task's TWA (max-min), ties by the mean",
    "rank": "the mean over the tasks of each configuration's rank percentile among the candidate configurations on "
            "that task (0 the worst, 1 the best; ties share their mean rank)",
    "family": "the method first (families ordered by the mean of their best ten configurations' mean TWA), then the "
              "mean TWA within the method",
    "smooth": "the mean over the tasks of the TWA averaged over the configuration's neighbouring windows (the same "
              "method, kind, combine and aggregation, each window within two steps of the sweep's window grid)",
}
#: The statistic ``fiper evaluate --write-prior`` and the leave-one-task-out priors rank by without
#: ``--prior-statistic``, per promise they rank at (:data:`~fiper_ros.core.auto.PROMISES`): each the one that beat
#: ``mean`` on the sim tasks and the real-policy development set at that promise by the criterion of docs/results.md,
#: "Which statistic the prior ranks by" (``mean`` kept at each entry's own promise).
DEFAULT_STATISTICS = {DELTA_PROMISE: "rank", ENTRY_PROMISE: "mean"}
#: The aggregations an entry may declare (a calibration's, :data:`fiper_ros.core.window.MODES`, but the single step,
#: which the sweep calls window 1).
AGGREGATIONS = ("window", "max", "cumulative")


class PriorError(AutoError):
    """A prior cannot be read or used (a damaged or modified file, an entry no calibration can declare, no entry
    that fits the task)."""


def _number(value: float) -> float | None:
    """A figure as the file writes it: rounded to 6 decimals, ``None`` for NaN."""
    return None if value is None or math.isnan(value) else round(float(value), 6)


@dataclass(frozen=True)
class PriorEntry:
    """One configuration of a prior and what it did on the prior's tasks.

    Attributes:
        detectors: The declared detectors, in the fusion's order.
        aggregation: ``"window"``, ``"max"`` (max-pooled) or ``"cumulative"``; a detector whose aggregation is fixed
            (the elapsed time) keeps its own.
        windows: Each windowed detector's window (empty for the cumulative sum and for fixed detectors alone).
        kind: The threshold kind (a guaranteed one).
        combine: ``"and"``, ``"or"``, ``"max"`` or ``"kth:K"``; empty for one detector.
        equalise, equalise_level: The joint combine's tail equalisation (:mod:`fiper_ros.core.equalisation`).
        method: The evaluation's method or combination it was swept as (for people).
        twa, tpr, tnr: Mean over the prior's tasks (and seeds) of the metrics averaged over the finite deltas.
        per_task: Each task's TWA.
    """

    detectors: tuple[str, ...]
    aggregation: str
    windows: Mapping[str, int]
    kind: str
    combine: str = ""
    equalise: str = "none"
    equalise_level: float = DEFAULT_LEVEL
    method: str = ""
    twa: float = math.nan
    tpr: float = math.nan
    tnr: float = math.nan
    per_task: Mapping[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        try:
            object.__setattr__(self, "detectors", in_fusion_order(tuple(check_declared(d) for d in self.detectors)))
            windows = {str(k): int(v) for k, v in dict(self.windows).items()}
            unknown = sorted(set(windows) - set(self.detectors))
            if unknown or min(windows.values(), default=1) < 1:
                raise PriorError(f"windows {windows} do not fit the detectors {','.join(self.detectors)}")
            object.__setattr__(self, "windows", {d: windows[d] for d in self.detectors if d in windows})
            check_equalisation(self.equalise, self.equalise_level)
            if self.equalise != "quantile":  # one form per meaning, as the calibration settings keep it
                object.__setattr__(self, "equalise_level", DEFAULT_LEVEL)
            if self.kind not in GUARANTEED_KINDS:
                raise PriorError(f"threshold {self.kind!r} keeps no promise; a prior entry has one of "
                                 f"{', '.join(GUARANTEED_KINDS)}")
            if self.aggregation not in AGGREGATIONS:
                raise PriorError(f"aggregation {self.aggregation!r}; expected one of {', '.join(AGGREGATIONS)}")
            if bool(self.combine) != (len(self.detectors) > 1):
                raise PriorError(f"{len(self.detectors)} detector(s) with combine {self.combine!r}: several detectors "
                                 "need a combine, one none")
            rule = Combine.parse(self.combine or "and")
            rule.votes(len(self.detectors))
            if self.equalise != "none" and not rule.joint:
                raise PriorError(f"equalise {self.equalise} applies to a joint combine, not {self.combine!r}")
        except PriorError:
            raise
        except (CoreError, ValueError, TypeError) as error:
            raise PriorError(str(error)) from error

    @property
    def promised_multiple(self) -> int:
        """How many deltas its false alarms on new successes are promised to stay under: ``N`` for an OR of ``N``
        thresholds (the union bound), else 1."""
        return Combine.parse(self.combine or CombineMode.AND.value).promised_multiple(len(self.detectors))

    def window_text(self) -> str:
        """``w5``, ``max5``, ``cum`` or ``rnd_oe w8, ace w50``."""
        if self.aggregation == "cumulative" or not self.windows:
            return "cum"
        prefix = "max" if self.aggregation == "max" else "w"
        if len(set(self.windows.values())) == 1:
            return f"{prefix}{next(iter(self.windows.values()))}"
        return ", ".join(f"{d} {prefix}{w}" for d, w in self.windows.items())

    def label(self) -> str:
        """For people: ``rnd_oe+ace w5 cp_band or (2 delta)``."""
        parts = ["+".join(self.detectors), self.window_text(), self.kind]
        parts += [self.combine] if self.combine else []
        parts += [f"{self.equalise}-equalised"] if self.equalise != "none" else []
        parts += [f"({self.promised_multiple} delta)"] if self.promised_multiple > 1 else []
        return " ".join(parts)

    def settings(self) -> dict[str, Any]:
        """The :class:`~fiper_ros.core.calibration.CalibrationSettings` fields the entry sets."""
        window = min(self.windows.values(), default=1)
        return {"detectors": self.detectors, "window": window, "windows": dict(self.windows),
                "aggregation": self.aggregation, "threshold": self.kind, "combine": self.combine or "and",
                "equalise": self.equalise, "equalise_level": self.equalise_level}

    def to_dict(self) -> dict[str, Any]:
        """Plain data (figures rounded; the promise written out)."""
        return {"detectors": list(self.detectors), "aggregation": self.aggregation, "windows": dict(self.windows),
                "kind": self.kind, "combine": self.combine, "equalise": self.equalise,
                "equalise_level": self.equalise_level, "promise": f"{self.promised_multiple} delta",
                "method": self.method, "twa": _number(self.twa), "tpr": _number(self.tpr), "tnr": _number(self.tnr),
                "per_task": {k: _number(v) for k, v in self.per_task.items()}}

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> PriorEntry:
        """Inverse of :meth:`to_dict` (:class:`PriorError` for a missing field or a promise that does not match)."""
        try:
            entry = cls(tuple(data["detectors"]), data["aggregation"], data["windows"], data["kind"], data["combine"],
                        data["equalise"], float(data["equalise_level"]), str(data["method"]),
                        *(math.nan if data[k] is None else float(data[k]) for k in ("twa", "tpr", "tnr")),
                        {k: math.nan if v is None else float(v) for k, v in data["per_task"].items()})
        except (KeyError, TypeError, AttributeError, ValueError) as error:
            raise PriorError(f"a prior entry lacks or mistypes a field ({error})") from None
        if data.get("promise") != f"{entry.promised_multiple} delta":
            raise PriorError(f"prior entry {entry.label()}: promise {data.get('promise')!r}, its combine promises "
                             f"{entry.promised_multiple} delta")
        return entry

    def key(self) -> tuple:
        """What a calibration declares of it: equal keys are the same configuration."""
        return (self.detectors, self.aggregation, tuple(self.windows.items()), self.kind, self.combine, self.equalise,
                self.equalise_level)


@dataclass(frozen=True)
class Prior:
    """A ranked list of configurations learned on labelled rollouts of ``tasks`` (module docstring).

    Attributes:
        entries: Best first.
        tasks: The tasks whose labelled test rollouts ranked them.
        seeds, deltas: Of the run that measured them; each entry's figures average its finite deltas.
        selection: How the entries were ranked (the subset, the statistic, the aggregations allowed).
        calibration: The calibration settings the run measured them with (profile, split, shape folds).
        made_from: One sentence: the data.
        command: The command that made it.
        version: The fiper-ros version that made it.
    """

    entries: tuple[PriorEntry, ...]
    tasks: tuple[str, ...]
    seeds: tuple[int, ...] = ()
    deltas: tuple[float, ...] = ()
    selection: Mapping[str, Any] = field(default_factory=dict)
    calibration: Mapping[str, Any] = field(default_factory=dict)
    made_from: str = ""
    command: str = ""
    version: str = ""

    def content(self) -> dict[str, Any]:
        """The file's content without its hash."""
        return {"format_version": PRIOR_FORMAT, "kind": PRIOR_KIND, "made_from": self.made_from,
                "command": self.command, "version": self.version, "tasks": list(self.tasks),
                "seeds": list(self.seeds), "deltas": list(self.deltas), "selection": dict(self.selection),
                "calibration": dict(self.calibration), "entries": [e.to_dict() for e in self.entries]}

    @property
    def content_hash(self) -> str:
        """SHA-256 over :meth:`content` (JSON, sorted keys)."""
        return _hash(self.content())

    def save(self, path: str | Path) -> Path:
        """Write the prior as YAML (with its content hash) to ``path``."""
        path = Path(path)
        data = {**self.content(), "content_hash": self.content_hash}
        temporary = path.with_name(f".{path.name}.tmp")
        temporary.write_text(yaml.safe_dump(data, sort_keys=False, allow_unicode=True))
        temporary.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path) -> Prior:
        """The prior file ``path``; :class:`PriorError` in one line for an unreadable, foreign or modified file."""
        path = Path(path)
        try:
            data = yaml.safe_load(path.read_text())
        except (OSError, yaml.YAMLError) as error:
            raise PriorError(f"{path}: not a readable prior ({' '.join(str(error).split())})") from None
        found = (data.get("kind"), data.get("format_version")) if isinstance(data, dict) else (None, None)
        if found != (PRIOR_KIND, PRIOR_FORMAT):
            raise PriorError(f"{path}: not a prior this code reads (kind {found[0]!r}, format_version {found[1]!r}; "
                             f"expected {PRIOR_KIND!r}, {PRIOR_FORMAT})")
        stored = data.pop("content_hash", None)
        if stored != _hash(data):
            raise PriorError(f"{path}: content hash mismatch (the prior was modified after it was written)")
        try:
            prior = cls(tuple(PriorEntry.from_dict(e) for e in data["entries"]), tuple(data["tasks"]),
                        tuple(data["seeds"]), tuple(data["deltas"]), data["selection"], data["calibration"],
                        data["made_from"], data["command"], data["version"])
        except PriorError as error:
            raise PriorError(f"{path}: {error}") from None
        except (KeyError, TypeError) as error:
            raise PriorError(f"{path}: a prior lacks or mistypes a field ({error})") from None
        if not prior.entries:
            raise PriorError(f"{path}: a prior without entries")
        statistic = prior.selection.get("statistic") if isinstance(prior.selection, Mapping) else None
        if statistic not in STATISTICS:
            raise PriorError(f"{path}: selection statistic {statistic!r} is not one this code knows "
                             f"({', '.join(STATISTICS)})")
        if prior_promise(prior) not in PROMISES:
            raise PriorError(f"{path}: selection promise {prior_promise(prior)!r} is not one this code knows "
                             f"({', '.join(PROMISES)})")
        return prior


def threshold_delta(entry: PriorEntry, delta: float, promise: str) -> float:
    """The delta each of ``entry``'s thresholds is calibrated at for a choice that keeps ``promise`` at ``delta``
    (:data:`~fiper_ros.core.auto.PROMISES`): ``delta`` for ``entry``, ``delta / N`` for an OR of ``N`` thresholds
    with ``delta`` (the union bound keeps its false alarms under ``N (delta / N) = delta``)."""
    if promise not in PROMISES:
        raise PriorError(f"promise {promise!r}; expected one of {', '.join(PROMISES)}")
    return delta / entry.promised_multiple if promise == DELTA_PROMISE else delta


def prior_promise(prior: Prior) -> str:
    """The promise a prior's entries were ranked at (its ``selection.promise``; ``entry`` in a prior without one)."""
    return str(prior.selection.get("promise", ENTRY_PROMISE))


def _hash(content: Mapping[str, Any]) -> str:
    return hashlib.sha256(json.dumps(content, sort_keys=True).encode()).hexdigest()


@dataclass(frozen=True)
class TransferChoice:
    """The chosen prior entry, its rank (1 = the best) and the entries ranked above it that did not fit, with why."""

    chosen: PriorEntry
    rank: int
    prior: Prior
    skipped: tuple[tuple[int, PriorEntry, str], ...]
    settings: AutoSettings
    delta: float
    detectors: tuple[str, ...]

    @property
    def threshold_delta(self) -> float:
        """The delta each of the chosen entry's thresholds is calibrated at (:func:`threshold_delta`)."""
        return threshold_delta(self.chosen, self.delta, self.settings.promise)

    def label(self) -> str:
        """The chosen entry's label, with the delta its thresholds take where the promise splits it."""
        if self.threshold_delta == self.delta:
            return self.chosen.label()
        return f"{self.chosen.label()} at delta/{self.chosen.promised_multiple} each"

    def why(self) -> str:
        """One sentence: why this entry."""
        tasks = ", ".join(self.prior.tasks)
        text = (f"{self.chosen.label()} is entry {self.rank} of {len(self.prior.entries)} of the prior learned on "
                f"{tasks} (mean TWA {self.chosen.twa:.3f} there)")
        if self.threshold_delta != self.delta:
            text += (f"; its {self.chosen.promised_multiple} thresholds at delta {self.threshold_delta:g} each keep "
                     f"the promise delta {self.delta:g}")
        if self.skipped:
            reasons: dict[str, int] = {}
            for _, _, reason in self.skipped:
                reasons[reason] = reasons.get(reason, 0) + 1
            text += "; above it " + ", ".join(f"{n} {reason}" for reason, n in reasons.items())
        return text

    def record(self, top: int = 10) -> dict[str, Any]:
        """What a calibration stores of the choice: the rule, the prior (hash, tasks), the rank and the entry."""
        return {"rule": TRANSFER, "version": RULES[TRANSFER], "delta": self.delta,
                "threshold_delta": self.threshold_delta, "settings": self.settings.to_dict(),
                "detectors": list(self.detectors),
                "prior": {"content_hash": self.prior.content_hash, "tasks": list(self.prior.tasks),
                          "entries": len(self.prior.entries), "made_from": self.prior.made_from},
                "rank": self.rank, "chosen": self.chosen.to_dict(), "why": self.why(),
                "skipped": [{"rank": r, "entry": e.label(), "why": why} for r, e, why in self.skipped[:top]]}


NOT_FED = "need a detector the successes cannot feed"
INFINITE = "have a +inf threshold at delta"


def choose_from_prior(prior: Prior, available: Sequence[str], finite: Callable[[PriorEntry], bool],
                      settings: AutoSettings, delta: float) -> TransferChoice:
    """The rule (module docstring): the first entry of ``prior`` whose detectors are all in ``available`` (what the
    task's successes can feed) and for which ``finite`` (its threshold at ``delta`` with the task's conformal
    successes) holds; :class:`PriorError` in one line if none does. Deterministic: the prior's order decides."""
    if settings.rule != TRANSFER:
        raise ValueError(f"choose_from_prior applies the rule {TRANSFER!r}, not {settings.rule!r}")
    fed = set(available)
    skipped: list[tuple[int, PriorEntry, str]] = []
    for rank, entry in enumerate(prior.entries, 1):
        missing = [d for d in entry.detectors if d not in fed]
        if missing:
            skipped.append((rank, entry, NOT_FED))
        elif not finite(entry):
            skipped.append((rank, entry, INFINITE))
        else:
            return TransferChoice(entry, rank, prior, tuple(skipped), settings, delta, tuple(available))
    fits = sum(1 for _, _, why in skipped if why == INFINITE)
    raise PriorError(f"no entry of the prior learned on {', '.join(prior.tasks)} fits this task: of its "
                     f"{len(prior.entries)} entries {len(skipped) - fits} need a detector the successes cannot feed "
                     f"({', '.join(available)}) and {fits} have a +inf threshold at delta {delta:g} (more successes "
                     "or a larger --delta)")
