"""Choosing a calibration's configuration from successful rollouts alone (``fiper calibrate --auto``).

A user calibrating a new task has successes and nothing else, so every choice a calibration leaves open (which
detectors, their window, the threshold kind, how they combine) has to be made without a failure. The rule here,
``proxy-twa``, scores every candidate configuration on the successes of the calibration's fit part only (the
conformal part stays untouched for the final thresholds, so Proposition 1 keeps holding for the chosen
configuration):

1. **Out-of-fold curves.** The fit part is split into ``folds`` folds; each fold's successes are scored by the
   detectors' models fitted on the other folds (:mod:`fiper_ros.core.calibration.auto`), so no curve comes from a
   model that saw its rollout.
2. **Failure proxies** made from each held-out success, scored by the same fold models (:func:`make_proxy`):
   ``stall`` (from a seeded step on, that step repeated up to the task's step limit: a rollout that stops
   progressing and runs into the time limit), ``drift`` (from a seeded step on, the embeddings moved along a
   seeded direction uniform on the sphere, growing linearly to ``drift_scale`` times the successes' total spread at
   the last step: a rollout that leaves the calibration manifold; in many dimensions a random direction lies mostly
   across the few directions the successes vary in), ``skip`` (a seeded block of a quarter of the steps dropped).
3. **Inner calibration.** Per inner fold of the out-of-fold curves, the rest is split into a shape half (the
   candidate's per-step shape, :func:`fiper_ros.core.combination.fit_shape`) and a quantile half (the
   ``1 - delta`` empirical quantile ``k`` of their ``max_t c(t)``, the combined statistic of
   :mod:`fiper_ros.core.combination`); the fold's held-out successes and their proxies are judged against ``k``.
   A proxy counts as caught only if the success it was made from stays below ``k`` (paired: a proxy alarmed like
   its own success was caught by the detector's noise, not by what was done to it).
4. **Score**: a time-weighted accuracy on the proxies (App. B.4's TWA with proxies as the failures), each kind
   weighed by what is achievable: ``0.5 (1 - held-out false-alarm rate) + 0.5 mean_kind (C_kind / max C_kind)``,
   ``C_kind`` the candidate's mean ``1 - t_alarm / T`` over the proxies of that kind (0 for a proxy not caught,
   averaged over tasks) and ``max C_kind`` the best candidate's (a kind no candidate catches is left out). The highest score wins; ties go to fewer held-out false alarms, then fewer
   detectors, then the smaller window, then the candidate order.

Why it should transfer to unseen failures: every candidate is calibrated to the same promise (``delta`` on
new successes), so the success half of the score differs only by sampling noise, and the proxy half rewards the
configuration whose threshold sits closest to the successes' own spread: a stall, a drift or a skip crosses a
tight threshold earlier than a loose one. A configuration that is tight only because of a quirk of the fit part
is not rewarded, because the threshold is always set on other successes than those judged. What it cannot know is
which kind of failure a task has: the proxies weigh the three kinds equally (docs/method.md, "Choosing the
configuration from successes").

The second rule, ``margin``, reads held-out successes only (no proxy): steps 1 and 3 as above, then per inner fold
the gap ``(k - c(t)) / s(t)`` between the threshold and every held-out success's statistic at each of its steps, in
units of ``s(t)``, the spread (standard deviation) of the shape half's statistic at that step; the candidate's
**margin** is the median gap over the folds' held-out successes and steps. The smallest margin wins (ties as
above): its threshold sits closest to the successes' own spread for the same promise, so a failure that leaves
the successes' band by a given number of spreads crosses it first. A candidate whose statistic has no spread at
any step (the elapsed time: every success has the same curve) has an infinite margin and is never chosen.

The third rule, ``transfer``, scores nothing of the task: it takes the best configuration of a prior learned on
other tasks' labelled rollouts that the task's successes can feed (:mod:`fiper_ros.core.transfer`).

No failure is ever read: the functions here take per-step scores of successes and of proxies made from them.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fiper_ros.core.calibration_file import CalibrationError
from fiper_ros.core.combination import SHAPE_KINDS, fit_shape
from fiper_ros.core.detectors import ELAPSED, in_fusion_order, info
from fiper_ros.core.fusion import Combine
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.thresholds import GUARANTEED_KINDS, ThresholdSettings, _quantile
from fiper_ros.core.window import aggregate

#: The rules (module docstring) and their versions (stored in the calibration with the choice).
PROXY_TWA = "proxy-twa"
MARGIN = "margin"
TRANSFER = "transfer"
RULES = {PROXY_TWA: 1, MARGIN: 1, TRANSFER: 1}
#: What each rule reads, in one sentence (reports say it).
RULE_SUMMARIES = {
    PROXY_TWA: "candidates scored on the fit part's successes by fold models, with stall, drift and skip proxies "
               "made from them",
    MARGIN: "candidates scored on the fit part's held-out successes alone (fold models; no proxy): the smallest "
            "margin between the threshold and the successes' statistic, in units of its per-step spread, wins",
    TRANSFER: "the highest-ranked configuration of a prior learned on other tasks' labelled rollouts that the "
              "task's successes can feed and whose threshold is finite at delta with its conformal successes",
}
#: What promise a ``transfer`` choice keeps at the calibration's delta (``--auto-promise``): ``delta`` (the default),
#: delta whatever the entry (an OR of ``N`` thresholds is calibrated at ``delta / N`` each, and a prior made for it
#: ranks every entry at equal promise); ``entry``, each entry its own (an OR of ``N`` thresholds at delta each promises
#: ``N delta``, the union bound). The other rules' candidates promise delta by construction (joint combines only), so
#: they take ``delta`` only.
ENTRY_PROMISE = "entry"
DELTA_PROMISE = "delta"
#: The promise ``--auto`` keeps without ``--auto-promise``: the delta the user asked for.
DEFAULT_PROMISE = DELTA_PROMISE
PROMISES = {
    ENTRY_PROMISE: "each entry keeps its own promise: an OR of N thresholds at delta each promises N delta",
    DELTA_PROMISE: "every choice promises delta: an OR of N thresholds is calibrated at delta / N each (the union "
                   "bound)",
}
#: The failure proxies the rule can build from a success.
PROXIES = ("stall", "drift", "skip")
#: Share of a success's steps before a proxy's onset: drawn uniformly in this range.
ONSET = (0.3, 0.7)
#: Share of a success's steps a ``skip`` proxy drops.
SKIPPED = 0.25


class AutoError(CalibrationError):
    """The automatic choice cannot be made (too many candidates for the budget, too few successes, ...)."""


@dataclass(frozen=True)
class AutoSettings:
    """What ``--auto`` tries and how it scores (module docstring).

    Attributes:
        rule: The rule (:data:`RULES`): ``proxy-twa`` scores failure proxies, ``margin`` held-out successes only,
            ``transfer`` takes a prior's entry (:mod:`fiper_ros.core.transfer`; the candidate options do not apply).
        windows: The windows tried for every detector whose aggregation is not fixed, kept sorted and distinct
            (their order means nothing and a repeat only spends the budget; a detector whose aggregation is fixed
            is tried once, with the smallest).
        kinds: Threshold kinds tried (guaranteed ones only); a combination of several detectors takes the kinds
            with a shape among them.
        combines: Joint combines tried for sets of several detectors.
        proxies: The failure proxies built from held-out successes.
        folds: Folds of the fit part (out-of-fold curves; also the final calibration's ``shape_folds``), and of
            the rule's inner calibration.
        repeats: Repeats of the inner calibration, each with its own seeded folds and halves (less noise in ``k``).
        budget: Most candidates evaluated; more is refused (fewer windows, kinds or detectors).
        drift_scale: A drift proxy's final offset, in units of the successes' total spread.
        stall_factor: Without a step limit, a stall proxy runs to this many times the longest success.
        step_limit: The task's step limit (a stall proxy runs to it), if given.
        promise: The promise at delta (:data:`PROMISES`, default :data:`DEFAULT_PROMISE`); ``entry`` is the
            ``transfer`` rule's only (the other rules' candidates promise delta).
    """

    rule: str = PROXY_TWA
    windows: tuple[int, ...] = (1, 3, 5, 10, 20)
    kinds: tuple[str, ...] = GUARANTEED_KINDS
    combines: tuple[str, ...] = ("max", "kth:2")
    proxies: tuple[str, ...] = PROXIES
    folds: int = 5
    repeats: int = 3
    budget: int = 400
    drift_scale: float = 1.0
    stall_factor: float = 1.5
    step_limit: int | None = None
    promise: str = DEFAULT_PROMISE

    def __post_init__(self) -> None:
        for name in ("windows", "kinds", "combines", "proxies"):
            object.__setattr__(self, name, tuple(getattr(self, name)))
        object.__setattr__(self, "windows", tuple(sorted(set(self.windows))))
        if self.rule not in RULES:
            raise AutoError(f"auto rule must be one of {', '.join(RULES)}, got {self.rule!r}")
        if not self.windows or min(self.windows) < 1:
            raise AutoError(f"auto windows must be >= 1, at least one, got {self.windows}")
        if not self.kinds or any(k not in GUARANTEED_KINDS for k in self.kinds):
            raise AutoError(f"auto threshold kinds must be among {', '.join(GUARANTEED_KINDS)}, got {self.kinds}")
        for text in self.combines:
            if not Combine.parse(text).joint:
                raise AutoError(f"auto combines must be joint (max, kth:K), got {text!r}")
        if not self.proxies or any(p not in PROXIES for p in self.proxies):
            raise AutoError(f"auto proxies must be among {', '.join(PROXIES)}, at least one, got {self.proxies}")
        if self.folds < 2 or self.repeats < 1:
            raise AutoError(f"auto folds must be >= 2 and repeats >= 1, got {self.folds}, {self.repeats}")
        if self.budget < 1:
            raise AutoError(f"auto budget must be >= 1, got {self.budget}")
        if not self.drift_scale > 0 or not self.stall_factor > 1:
            raise AutoError(f"auto drift_scale must be > 0 and stall_factor > 1, got {self.drift_scale}, "
                            f"{self.stall_factor}")
        if self.step_limit is not None and self.step_limit < 2:
            raise AutoError(f"step limit must be >= 2, got {self.step_limit}")
        if self.promise not in PROMISES:
            raise AutoError(f"auto promise must be one of {', '.join(PROMISES)}, got {self.promise!r}")
        if self.promise != DELTA_PROMISE and self.rule != TRANSFER:
            raise AutoError(f"--auto-promise {self.promise} applies to the transfer rule: the {self.rule} rule's "
                            "candidates promise delta (joint combines only)")

    def to_dict(self) -> dict[str, Any]:
        """Plain data (lists for tuples)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass(frozen=True)
class Candidate:
    """One configuration: the detectors, their window, the threshold kind and (several detectors) the combine."""

    detectors: tuple[str, ...]
    window: int
    kind: str
    combine: str = ""

    @property
    def votes(self) -> int:
        """Detectors that must exceed at a step (1 for one detector)."""
        return Combine.parse(self.combine).votes(len(self.detectors)) if self.combine else 1

    def label(self) -> str:
        """For people: ``rnd_oe+progress w5 cp_band kth:2``."""
        fixed = all(info(d).aggregation for d in self.detectors)
        window = "" if fixed else f" w{self.window}"
        return f"{'+'.join(self.detectors)}{window} {self.kind}{' ' + self.combine if self.combine else ''}"

    def settings(self) -> dict[str, Any]:
        """The :class:`~fiper_ros.core.calibration.CalibrationSettings` fields the candidate sets."""
        return {"detectors": self.detectors, "window": self.window, "windows": {}, "aggregation": "window",
                "threshold": self.kind, "combine": self.combine or "and"}

    def to_dict(self) -> dict[str, Any]:
        """Plain data."""
        return {"detectors": list(self.detectors), "window": self.window, "kind": self.kind, "combine": self.combine}


def detector_sets(detectors: Sequence[str]) -> list[tuple[str, ...]]:
    """The detector sets tried, each in the fusion's order (logged signals by name): each detector alone, all together, all but the elapsed
    time and the fitted ones alone (each set once, with at least two detectors for the sets)."""
    given = in_fusion_order(sorted(set(detectors)))
    sets: list[tuple[str, ...]] = [(d,) for d in given]
    for members in (given, tuple(d for d in given if d != ELAPSED), tuple(d for d in given if info(d).fitted)):
        if len(members) >= 2 and members not in sets:
            sets.append(members)
    return sets


def candidates(detectors: Sequence[str], settings: AutoSettings) -> list[Candidate]:
    """Every candidate for ``detectors``; :class:`AutoError` if there are more than ``settings.budget``."""
    if not detectors:
        raise AutoError("auto needs at least one candidate detector")
    out: list[Candidate] = []
    for members in detector_sets(detectors):
        fixed = all(info(d).aggregation for d in members)
        windows = settings.windows[:1] if fixed else settings.windows
        if len(members) == 1:
            kinds = ("cp_constant",) if members == (ELAPSED,) else settings.kinds
            out.extend(Candidate(members, w, k) for w in windows for k in kinds)
            continue
        combines = [c for c in settings.combines if Combine.parse(c).k <= len(members)]
        out.extend(Candidate(members, w, k, c) for w in windows for k in settings.kinds if k in SHAPE_KINDS
                   for c in combines)
    if len(out) > settings.budget:
        raise AutoError(f"{len(out)} candidate configurations exceed the auto budget of {settings.budget} "
                        "(--auto-budget): try fewer windows, kinds or detectors")
    return out


@dataclass(frozen=True)
class EmbeddingSpread:
    """The successes' per-dimension embedding standard deviation; its :attr:`total` is the drift proxy's scale."""

    std: np.ndarray

    @classmethod
    def of(cls, successes: Sequence[Rollout]) -> EmbeddingSpread:
        """Over every step of ``successes``."""
        return cls(np.concatenate([r.embeddings for r in successes]).astype(np.float64).std(axis=0))

    @property
    def total(self) -> float:
        """``sqrt(sum_d var_d)``: the RMS distance of an embedding from the mean."""
        return float(np.sqrt(np.sum(self.std ** 2)))


def _onset(rng: np.random.Generator, length: int) -> int:
    low = int(round(ONSET[0] * length))
    return int(rng.integers(low, max(int(round(ONSET[1] * length)), low + 1)))


def _reindexed(rollout: Rollout, index: np.ndarray, kind: str, embeddings: np.ndarray | None = None) -> Rollout:
    """``rollout`` at the steps ``index`` (embeddings, actions, signals and per-step metadata alike)."""
    length = rollout.length
    metadata = {k: (v[index] if isinstance(v, np.ndarray) and v.ndim and v.shape[0] == length else v)
                for k, v in rollout.metadata.items()}
    return Rollout(f"{rollout.rollout_id}~{kind}", rollout.task, rollout.scenario,
                   rollout.embeddings[index] if embeddings is None else embeddings,
                   None if rollout.actions is None else rollout.actions[index], rollout.exec_steps, None,
                   rollout.action_space, metadata, {k: v[index] for k, v in rollout.signals.items()})


def make_proxy(rollout: Rollout, kind: str, rng: np.random.Generator, spread: EmbeddingSpread,
               stall_length: int, drift_scale: float) -> Rollout:
    """The failure proxy ``kind`` (:data:`PROXIES`) made from the success ``rollout`` (module docstring); its
    outcome is unknown (``success=None``): it is no labelled failure."""
    length = rollout.length
    steps = np.arange(length)
    if kind == "stall":
        onset = _onset(rng, length)
        total = max(stall_length, length + 1)
        return _reindexed(rollout, np.concatenate([steps[: onset + 1], np.full(total - onset - 1, onset)]), kind)
    if kind == "skip":
        if length < 4:
            return _reindexed(rollout, steps, kind)
        dropped = max(1, int(round(SKIPPED * length)))
        start = int(rng.integers(1, max(length - dropped, 2)))
        return _reindexed(rollout, np.concatenate([steps[:start], steps[start + dropped:]]), kind)
    if kind == "drift":
        onset = _onset(rng, length)
        direction = rng.standard_normal(spread.std.shape[0])
        direction /= np.linalg.norm(direction)
        ramp = np.clip((steps - onset) / max(length - 1 - onset, 1), 0.0, 1.0)
        offset = (drift_scale * spread.total) * ramp[:, None] * direction[None, :]
        return _reindexed(rollout, steps, kind, rollout.embeddings + offset.astype(np.float32))
    raise AutoError(f"unknown proxy {kind!r}; expected one of {', '.join(PROXIES)}")


def stall_length(successes: Sequence[Rollout], settings: AutoSettings) -> int:
    """How long a stall proxy runs: the step limit, else ``stall_factor`` times the longest success."""
    if settings.step_limit is not None:
        return settings.step_limit
    return int(math.ceil(settings.stall_factor * max(r.length for r in successes)))


@dataclass
class TaskScores:
    """One task's per-step scores for the rule: per detector, the out-of-fold scores of the fit part's successes
    (in order) and of the proxies, each proxy's kind and the success it was made from (an index)."""

    successes: dict[str, list[np.ndarray]]
    proxies: dict[str, list[np.ndarray]] = field(default_factory=dict)
    proxy_kinds: tuple[str, ...] = ()
    proxy_sources: tuple[int, ...] = ()

    @property
    def count(self) -> int:
        """Successes."""
        return len(next(iter(self.successes.values())))


@dataclass(frozen=True)
class Score:
    """One candidate's figures: the score, the held-out false-alarm rate and what the rule measured, averaged over
    tasks: ``proxy-twa`` each proxy kind's mean ``1 - t/T`` (0 where never alarmed), ``margin`` the ``margin``."""

    candidate: Candidate
    score: float
    false_alarms: float
    caught: dict[str, float]

    def row(self) -> dict[str, Any]:
        """Plain data."""
        return {"candidate": self.candidate.label(), "score": round(self.score, 6),
                "false_alarms": round(self.false_alarms, 6),
                "figures": {k: round(v, 6) for k, v in self.caught.items()}}


@dataclass(frozen=True)
class AutoChoice:
    """The chosen candidate, every candidate's figures (best first) and what was tried."""

    chosen: Candidate
    ranking: tuple[Score, ...]
    settings: AutoSettings
    delta: float
    detectors: tuple[str, ...]

    def why(self) -> str:
        """One sentence: why the winner won."""
        best = self.ranking[0]
        if self.settings.rule == MARGIN:
            text = (f"{best.candidate.label()} has the smallest margin {best.caught[MARGIN]:.3f} of "
                    f"{len(self.ranking)} candidates (held-out successes alarmed {best.false_alarms:.2f})")
        else:
            caught = ", ".join(f"{k} {v:.2f}" for k, v in best.caught.items())
            text = (f"{best.candidate.label()} has the highest proxy TWA {best.score:.3f} of {len(self.ranking)} "
                    f"candidates (held-out successes alarmed {best.false_alarms:.2f}; proxies caught, 1 - t/T: "
                    f"{caught})")
        if len(self.ranking) > 1:
            second = self.ranking[1]
            text += f"; next {second.candidate.label()} {second.score:.3f}"
        return text

    def record(self, top: int = 10) -> dict[str, Any]:
        """What a calibration stores of the choice."""
        return {"rule": self.settings.rule, "version": RULES[self.settings.rule], "delta": self.delta, "settings": self.settings.to_dict(),
                "detectors": list(self.detectors), "chosen": self.chosen.to_dict(), "candidates": len(self.ranking),
                "why": self.why(), "top": [s.row() for s in self.ranking[:top]]}


def _aggregated(scores: Sequence[np.ndarray], detector: str, window: int, length: int) -> np.ndarray:
    """``[N, length]`` windowed curves (NaN past each end)."""
    mode = info(detector).aggregation or "window"
    out = np.full((len(scores), length), np.nan)
    for i, s in enumerate(scores):
        out[i, : s.shape[0]] = aggregate(np.asarray(s, dtype=np.float64), mode, window)
    return out


def _folds(count: int, folds: int, repeats: int, seed: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per inner fold of every repeat: the held-out successes, the shape half and the quantile half of the rest
    (seeded; each repeat its own permutation, every success held out once per repeat)."""
    out = []
    for repeat in range(repeats):
        rng = np.random.default_rng([seed, 41, repeat])
        order = rng.permutation(count)
        for held in np.array_split(order, min(folds, count)):
            rest = rng.permutation(np.setdiff1d(order, held))
            half = max(1, rest.shape[0] // 2)
            out.append((np.sort(held), np.sort(rest[:half]), np.sort(rest[half:] if rest.shape[0] > 1 else rest)))
    return out


class _TaskRule:
    """The rule's work on one task: curves, shapes and statistics cached per (detector, window, kind, fold)."""

    def __init__(self, data: TaskScores, base: ThresholdSettings, folds: int, repeats: int, seed: int) -> None:
        if data.count < 4:
            raise AutoError(f"auto needs at least 4 successes in the fit part, got {data.count}")
        self.data, self.base = data, base
        self.length = max(s.shape[0] for per in (data.successes, data.proxies) for d in per for s in per[d])
        self.rows = data.count + len(data.proxy_kinds)
        self.lengths = np.array([s.shape[0] for s in next(iter(data.successes.values()))]
                                + [s.shape[0] for s in next(iter(data.proxies.values()), [])])
        self.folds = _folds(data.count, folds, repeats, seed)
        self.repeats = repeats
        self.sources = np.array(data.proxy_sources, dtype=int)
        self.kinds = np.array(data.proxy_kinds)
        self._curves: dict[tuple[str, int], np.ndarray] = {}
        self._z: dict[tuple[str, int, str, int], np.ndarray] = {}

    def curves(self, detector: str, window: int) -> np.ndarray:
        key = (detector, window)
        if key not in self._curves:
            scores = [*self.data.successes[detector], *self.data.proxies.get(detector, [])]
            self._curves[key] = _aggregated(scores, detector, window, self.length)
        return self._curves[key]

    def statistic(self, detector: str, window: int, kind: str, fold: int) -> np.ndarray:
        """``z(t)`` of every row under the shape fitted on the fold's shape half (the curves for CP constant)."""
        if kind == "cp_constant":
            return self.curves(detector, window)
        kind = info(detector).shape or kind
        key = (detector, window, kind, fold)
        if key not in self._z:
            curves = self.curves(detector, window)
            shape_rows = self.folds[fold][1]
            shape = fit_shape([curves[i, : self.lengths[i]] for i in shape_rows], self.length, kind, self.base)
            self._z[key] = (curves - shape.offset[None, :]) / shape.scale[None, :]
        return self._z[key]

    def combined(self, candidate: Candidate, fold: int) -> np.ndarray:
        """The candidate's statistic ``c(t)`` of every row in ``fold`` (``-inf`` past each end)."""
        z = np.stack([self.statistic(d, candidate.window, candidate.kind, fold) for d in candidate.detectors])
        return np.sort(np.nan_to_num(z, nan=-np.inf), axis=0)[z.shape[0] - candidate.votes]

    def margin(self, candidate: Candidate, delta: float) -> tuple[float, float]:
        """Held-out false-alarm rate and the margin (module docstring) over the inner folds."""
        alarms = 0
        gaps: list[float] = []
        for f, (held, shape_rows, quantile_rows) in enumerate(self.folds):
            c = self.combined(candidate, f)
            peaks = c.max(axis=1)
            k = _quantile(peaks[quantile_rows], delta, False)
            alarms += int(np.sum(peaks[held] > k))
            reference = c[shape_rows]
            counted = np.isfinite(reference)
            steps = counted.sum(axis=0)
            mean = np.where(counted, reference, 0.0).sum(axis=0) / np.maximum(steps, 1)
            spread = np.sqrt(np.where(counted, (reference - mean) ** 2, 0.0).sum(axis=0) / np.maximum(steps, 1))
            for i in held:
                length = self.lengths[i]
                usable = (steps[:length] >= 2) & (spread[:length] > 0)
                if not np.isfinite(k) or not usable.any():
                    gaps.append(math.inf)
                    continue
                gaps.append(float(np.median((k - c[i, :length][usable]) / spread[:length][usable])))
        return alarms / (self.data.count * self.repeats), float(np.median(gaps))

    def judge(self, candidate: Candidate, delta: float) -> tuple[float, dict[str, float]]:
        """Held-out false-alarm rate and per proxy kind the mean ``1 - t/T``, over the inner folds."""
        alarms = 0
        caught: dict[str, list[float]] = {}
        for f, (held, _, quantile_rows) in enumerate(self.folds):
            c = self.combined(candidate, f)
            peaks = c.max(axis=1)
            k = _quantile(peaks[quantile_rows], delta, False)
            alarms += int(np.sum(peaks[held] > k))
            for p in np.flatnonzero(np.isin(self.sources, held)):
                row = self.data.count + p
                above = np.flatnonzero(c[row] > k)
                # paired: only a proxy whose own success stays below k is caught by what was done to it
                clean = peaks[self.sources[p]] <= k
                value = 1.0 - above[0] / self.lengths[row] if above.size and clean else 0.0
                caught.setdefault(str(self.kinds[p]), []).append(value)
        return alarms / (self.data.count * self.repeats), {kind: float(np.mean(v)) for kind, v in caught.items()}


def choose(tasks: Mapping[str, TaskScores], detectors: Sequence[str], settings: AutoSettings,
           base: ThresholdSettings, seed: int) -> AutoChoice:
    """The rule (module docstring) over ``tasks`` at ``base.delta``: every candidate of ``detectors`` (in the fusion's
    order, whatever their order here) scored, the best chosen. Deterministic for ``seed``."""
    if settings.rule == TRANSFER:
        raise ValueError("the transfer rule chooses from a prior (core.transfer.choose_from_prior), not from scores")
    if not tasks:
        raise AutoError("auto needs the successes of at least one task")
    detectors = in_fusion_order(sorted(set(detectors)))
    pool = candidates(detectors, settings)
    rules = {name: _TaskRule(data, base, settings.folds, settings.repeats, seed) for name, data in tasks.items()}
    if settings.rule == MARGIN:
        scores = []
        for candidate in pool:
            rates, margins = zip(*(rule.margin(candidate, base.delta) for rule in rules.values()))
            margin = float(np.mean(margins))
            scores.append(Score(candidate, -margin, float(np.mean(rates)), {MARGIN: margin}))
        return _ranked(pool, scores, settings, base.delta, detectors)
    judged = []
    for candidate in pool:
        rates, caught = [], []
        for rule in rules.values():
            rate, per_kind = rule.judge(candidate, base.delta)
            rates.append(rate)
            caught.append(per_kind)
        kinds = [k for k in settings.proxies if any(k in per for per in caught)]
        judged.append((float(np.mean(rates)), {k: float(np.mean([per[k] for per in caught if k in per]))
                                               for k in kinds}))
    # each kind's credit relative to the best candidate's: a kind that is hard to catch weighs as much as an easy one
    best = {k: max(c.get(k, 0.0) for _, c in judged) for k in settings.proxies}
    scores = []
    for candidate, (false_alarms, mean_caught) in zip(pool, judged):
        relative = [mean_caught.get(k, 0.0) / best[k] for k in settings.proxies if best[k] > 0]
        positive = float(np.mean(relative)) if relative else 0.0
        scores.append(Score(candidate, 0.5 * (1.0 - false_alarms) + 0.5 * positive, false_alarms, mean_caught))
    return _ranked(pool, scores, settings, base.delta, detectors)


def _ranked(pool: Sequence[Candidate], scores: Sequence[Score], settings: AutoSettings, delta: float,
            detectors: Sequence[str]) -> AutoChoice:
    """The choice: the highest score; ties to fewer held-out false alarms, fewer detectors, the smaller window, then
    the candidate order."""
    order = sorted(range(len(scores)), key=lambda i: (-scores[i].score, scores[i].false_alarms,
                                                      len(pool[i].detectors), pool[i].window, i))
    ranking = tuple(scores[i] for i in order)
    return AutoChoice(ranking[0].candidate, ranking, settings, delta, tuple(detectors))
