"""The evaluation run: scores (cached) -> sweep -> metrics -> protocols, for several tasks and seeds."""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from contextlib import nullcontext
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from fiper_ros.cluster import connected
from fiper_ros.core.auto import DEFAULT_PROMISE, DELTA_PROMISE, PROMISES, TRANSFER, AutoSettings
from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.combination import SHAPE_KINDS
from fiper_ros.core.profiles import get_profile
from fiper_ros.core.transfer import DEFAULT_STATISTICS, PRIOR_TOP, STATISTICS, Prior
from fiper_ros.evaluation.auto import AutoOutcome, auto_evaluation
from fiper_ros.evaluation.cache import ScoreCache, StreamScores
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.distributed import score_on_ray, sweep_on_ray
from fiper_ros.evaluation.dump import Dump
from fiper_ros.evaluation.early import DEFAULT_Q, EarlyDetection, TaskStatistics, areas, early_detection
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.external import check_external
from fiper_ros.evaluation.joint_sweep import JOINT_COMBINE_DEFAULTS, joint_sweep
from fiper_ros.evaluation.methods import (METHODS, Combination, Method, MethodSettings, method_of, pooled_methods,
                                          streams_of)
from fiper_ros.evaluation.progress import Progress
from fiper_ros.evaluation.protocol import (METRICS, ON_ONE_SUBSET, PROTOCOLS, SUBSETS, ProtocolResult, alarm_metrics,
                                           run_clean_task, run_protocol, validation_split)
from fiper_ros.evaluation.scoring import check_dataset, compute_streams
from fiper_ros.evaluation.sweep import FIPER, Group, SweepSettings, TaskSweep, sweep_task
from fiper_ros.evaluation.transfer import (chosen_groups, members_of, prior_header, ranked_prior,
                                           transfer_evaluation)

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class EngineSettings:
    """Everything an evaluation run depends on besides the data.

    Attributes:
        methods: Method names (:data:`fiper_ros.evaluation.methods.METHODS`, and ``external_<name>`` for the
            external scores of ``method_settings.external``), in table order.
        seeds: Seeds of the learned scores and of the CP band split.
        sweep: Windows, deltas, threshold kinds, FIPER pairs and combines.
        method_settings: Hyperparameters of every score stream (and the profile).
        protocols: Some of :data:`fiper_ros.evaluation.protocol.PROTOCOLS`.
        split_seed: Seed of the clean protocol's validation/report split.
        default_window, default_kind: The fixed default configuration.
        select_aggregations: Aggregations a method's configuration may be selected from.
        threads: torch threads while scores are computed.
        progress: Draw progress lines on stderr.
        combinations: Combinations evaluated beside the methods (:mod:`fiper_ros.evaluation.joint_sweep`).
        combines: The combines a combination of several detectors is swept with.
        pooled: Thresholds pooled over the tasks (each task normalised by its own shapes, one conformal factor
            over every task's conformal rollouts) for every method, instead of per task; normalisation kinds
            only (CP band, CP scaled).
        q_auc: ``q`` of the q-AUC: each rollout's maximum over its first ``ceil(q T_max)`` steps
            (:mod:`fiper_ros.evaluation.early`).
        auto: With settings: each task's configuration also chosen by ``fiper calibrate --auto`` on its calibration
            successes alone (:mod:`fiper_ros.evaluation.auto`), or with the ``transfer`` rule by a prior
            (:mod:`fiper_ros.evaluation.transfer`); ``None``: not.
        auto_prior: The ``transfer`` rule's prior for every task; ``None``: each task's made of the other tasks' labelled
            metrics of the run (two tasks or more).
        prior_top: Entries a prior made of the run's metrics keeps.
        prior_statistic: What a prior made of the run's metrics ranks by (:data:`fiper_ros.core.transfer.STATISTICS`):
            the leave-one-task-out priors of ``transfer`` and ``--write-prior``'s; ``None``: the default at
            ``promise`` (:data:`fiper_ros.core.transfer.DEFAULT_STATISTICS`, :attr:`statistic`).
        promise: The promise those priors rank their entries at and ``--auto`` keeps (``--auto-promise``,
            :data:`fiper_ros.core.auto.PROMISES`; ``auto``'s own when given).
    """

    methods: tuple[str, ...] = tuple(METHODS)
    seeds: tuple[int, ...] = (0,)
    sweep: SweepSettings = field(default_factory=SweepSettings)
    method_settings: MethodSettings = field(default_factory=MethodSettings)
    protocols: tuple[str, ...] = ("paper",)
    split_seed: int = 0
    default_window: int = 5
    default_kind: str = "cp_band"
    select_aggregations: tuple[str, ...] = ("window", "max")
    threads: int = 1
    progress: bool = True
    combinations: tuple[Combination, ...] = ()
    combines: tuple[str, ...] = JOINT_COMBINE_DEFAULTS
    pooled: bool = False
    q_auc: float = DEFAULT_Q
    auto: AutoSettings | None = None
    auto_prior: Prior | None = None
    prior_top: int = PRIOR_TOP
    prior_statistic: str | None = None
    promise: str = DEFAULT_PROMISE

    @property
    def statistic(self) -> str:
        """What a prior made of the run's metrics ranks by: ``prior_statistic``, else the default at ``promise``."""
        return self.prior_statistic or DEFAULT_STATISTICS[self.promise]

    def __post_init__(self) -> None:
        streams_of(list(self.methods))
        names = [*self.methods, *(c.name for c in self.combinations)]
        if len(set(names)) != len(names):
            raise SettingsError(f"method and combination names must be distinct, got {names}")
        if self.auto is not None and self.method_settings.split != "split":
            raise SettingsError("--auto chooses on the fit part of a split conformal calibration (--split split), not "
                             f"--split {self.method_settings.split}")
        if self.auto is not None and self.auto.rule != TRANSFER and self.pooled:
            raise SettingsError(f"--auto-rule {self.auto.rule} is evaluated with each task's choice calibrated on that "
                                "task alone, not pooled over the tasks (--pool): use --auto-rule transfer with --pool")
        if self.auto_prior is not None and (self.auto is None or self.auto.rule != TRANSFER):
            raise SettingsError("--auto-prior is the prior of --auto --auto-rule transfer")
        if self.prior_top < 1:
            raise SettingsError(f"--prior-top must be >= 1, got {self.prior_top}")
        if self.prior_statistic is not None and self.prior_statistic not in STATISTICS:
            raise SettingsError(f"--prior-statistic {self.prior_statistic!r}; expected one of {', '.join(STATISTICS)}")
        if self.promise not in PROMISES:
            raise SettingsError(f"--auto-promise {self.promise!r}; expected one of {', '.join(PROMISES)}")
        if self.sweep.or_promise == DELTA_PROMISE and self.promise != DELTA_PROMISE:
            raise SettingsError(f"--or-promise {DELTA_PROMISE} sweeps every OR at delta / N: its priors and --auto keep "
                                f"that promise (--auto-promise {DELTA_PROMISE}), not {self.promise!r}")
        if self.auto is not None and self.auto.promise != self.promise:
            raise SettingsError(f"--auto keeps promise {self.auto.promise!r}, the run's priors rank at {self.promise!r}")
        if (self.combinations or self.pooled) and self.method_settings.split != "split":
            raise SettingsError("combinations and pooled thresholds take their shapes from the fit part of a split "
                             f"conformal calibration (--split split), not from --split {self.method_settings.split}")
        if self.pooled and any(k not in SHAPE_KINDS for k in self.sweep.kinds):
            raise SettingsError(f"pooled thresholds normalise each task by its shapes: kinds among {SHAPE_KINDS}, got "
                             f"{self.sweep.kinds}")
        if any(p not in PROTOCOLS for p in self.protocols):
            raise SettingsError(f"protocols must be among {PROTOCOLS}, got {self.protocols}")
        if not self.seeds:
            raise SettingsError("at least one seed is needed")
        if not 0.0 < self.q_auc <= 1.0:
            raise SettingsError(f"--q-auc must be in (0, 1], got {self.q_auc:g}")
        if min(*self.seeds, self.split_seed) < 0:
            raise SettingsError(f"seeds must be >= 0, got --seeds {','.join(map(str, self.seeds))} and --split-seed "
                             f"{self.split_seed}")

    def calibration_settings(self, seed: int) -> CalibrationSettings:
        """The core calibration settings whose threshold rules and split the sweep uses (profile, split, seed)."""
        return self.method_settings.calibration_settings(seed)

    @property
    def halved(self) -> bool:
        """Whether a protocol selects on a validation half of the test rollouts and reports on the other
        (:data:`~fiper_ros.evaluation.protocol.SUBSETS`)."""
        return any(SUBSETS[p][1] == "report" for p in self.protocols)

    @property
    def columns(self) -> tuple[str, ...]:
        """Every evaluated method and combination, in table order."""
        return (*self.methods, *(c.name for c in self.combinations))

    def catalogue(self) -> dict[str, Method]:
        """The table column of every method and combination name."""
        return {**METHODS, **{m: method_of(m) for m in self.methods}, **{c.name: c.method() for c in self.combinations}}

    def combined_detectors(self) -> dict[str, tuple[str, ...]]:
        """The detectors of every method swept as a combination: the combinations, and every method when pooled; none
        for an equalised combination (its threshold-free statistic is not computed, :func:`~.early.statistic_of`)."""
        pooled = pooled_methods(self.methods) if self.pooled else ()
        return {c.name: c.detectors if c.equalise == "none" else () for c in (*pooled, *self.combinations)}

    def streams(self) -> list[str]:
        """Every stream the methods and combinations read."""
        return list(dict.fromkeys([*streams_of(list(self.methods)), *(d for c in self.combinations for d in c.detectors)]))


@dataclass
class SweepOutcome:
    """Every configuration's numbers over all tasks and seeds.

    ``metrics[subset]`` is ``[tasks, seeds, groups, deltas, 5]`` for subsets ``"all"`` and, with the
    clean protocol, ``"validation"`` and ``"report"``, NaN where a threshold is +inf (``infinite``,
    ``[tasks, seeds, groups, deltas]``; ``conformal`` ``[tasks, seeds, groups]`` counts the rollouts behind
    each configuration's conformal quantile). ``held_out[subset]`` ``[tasks, seeds, groups, deltas]`` is the
    false-alarm rate on the ID successes of the test rollouts (``"all"``) or of the report half
    (``"report"``), and ``id_successes[subset]`` their number per task.
    """

    groups: list[Group]
    metrics: dict[str, np.ndarray]
    infinite: np.ndarray
    conformal: np.ndarray
    held_out: dict[str, np.ndarray]
    id_successes: dict[str, list[int]]
    early: dict[str, np.ndarray] = field(default_factory=dict)
    """Threshold-free figures of every configuration on all test rollouts (:mod:`.early`): ``"auroc"`` and
    ``"q_auc"`` ``[tasks, seeds, groups]``, ``"pooled_auroc"`` and ``"pooled_q_auc"`` ``[seeds, groups]`` over
    every task's rollouts; NaN where a class is empty or a configuration has no statistic."""
    early_seconds: float = 0.0
    """Seconds spent on :attr:`early` (inside the sweep's time)."""


@dataclass
class EvaluationResult:
    """All numbers of one run. ``streams`` keeps the first seed's scores for plots."""

    settings: EngineSettings
    datasets: list[Dataset]
    sweep: SweepOutcome
    protocols: dict[str, ProtocolResult]
    streams: dict[str, dict[str, StreamScores]]
    timings: dict[str, float]
    cache_hits: int = 0
    cache_misses: int = 0
    early: dict[str, dict[str, EarlyDetection]] = field(default_factory=dict)
    """Per protocol, every selected configuration's AUROC and q-AUC on the rollouts it is reported on."""
    auto: AutoOutcome | None = None
    """``--auto``'s choice per task and its metrics (:mod:`fiper_ros.evaluation.auto`); ``None``: not asked for."""

    @property
    def tasks(self) -> list[str]:
        """Task names in input order."""
        return [d.task for d in self.datasets]

    @property
    def groups(self) -> list[Group]:
        """Every configuration (without its delta)."""
        return self.sweep.groups

    @property
    def metrics(self) -> dict[str, np.ndarray]:
        """Metrics per subset (:class:`SweepOutcome`)."""
        return self.sweep.metrics


def horizons(dataset: Dataset, profile: str) -> np.ndarray | int:
    """``T`` of the DT formula: each rollout's own length (paper, App. B.4: a failed episode of length ``T``
    flagged at ``t`` is predicted right at ``T - t`` of its ``T`` steps) or ``T_max`` over both splits
    (reference: the authors' code, ``t / (T_max - 1)``)."""
    return dataset.lengths if get_profile(profile).dt_mode == "paper" else dataset.max_length


def check_evaluation(datasets: Sequence[Dataset], settings: EngineSettings) -> None:
    """Refuse, before any work, what the run would stop on (:class:`DatasetError`): task names that are not
    distinct, each dataset's :func:`~fiper_ros.evaluation.scoring.check_dataset`, and external scores that do not
    match the data (:func:`~fiper_ros.evaluation.external.check_external`)."""
    tasks = [d.task for d in datasets]
    if len(set(tasks)) != len(tasks):
        raise DatasetError(f"task names must be distinct, got {tasks}")
    if settings.auto is not None and settings.auto.rule == TRANSFER and settings.auto_prior is None and len(tasks) < 2:
        raise DatasetError(f"--auto-rule transfer takes each task's prior from the other tasks' labelled rollouts: with "
                           f"one task ({tasks[0]}) give a prior file, --auto-prior FILE")
    if "loto" in settings.protocols and len(tasks) < 2:
        raise DatasetError(f"--protocol loto leaves one task out at a time: it needs two tasks or more, got "
                           f"{len(tasks)} ({', '.join(tasks)})")
    streams = settings.streams()
    for dataset in datasets:
        check_dataset(dataset, settings.method_settings, streams)
    check_external(datasets, settings.method_settings.external, streams)


def score_all(
    datasets: Sequence[Dataset], settings: EngineSettings, cache: ScoreCache | None, address: str | None = None,
    cpus: int | None = None,
) -> tuple[dict[tuple[str, int], dict[str, StreamScores]], float]:
    """Scores of every (task, seed); returns them and the seconds spent computing (not reading) them. With an
    ``address`` (:mod:`fiper_ros.cluster`; ``cpus``: of a local instance) the streams are computed as Ray tasks
    (:func:`~fiper_ros.evaluation.distributed.score_on_ray`), to the same scores."""
    streams = settings.streams()
    progress = Progress("scores", len(datasets) * len(settings.seeds), settings.progress)
    if address is not None:
        try:
            return score_on_ray(datasets, streams, settings.method_settings, settings.seeds, cache, settings.threads,
                                progress, address, cpus)
        finally:
            progress.close()
    out: dict[tuple[str, int], dict[str, StreamScores]] = {}
    computing = 0.0
    for dataset in datasets:
        for seed in settings.seeds:
            scores, seconds = compute_streams(dataset, streams, settings.method_settings, seed, cache,
                                              settings.threads)
            out[(dataset.task, seed)] = scores
            computing += sum(seconds.values())
            progress.advance(note=f"{dataset.task} seed {seed}")
    progress.close()
    return out, computing


def sweep_seed(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
               settings: EngineSettings, seed: int, thresholds: bool = False) -> dict[str, TaskSweep]:
    """Every configuration of one seed, per task: per task (:func:`sweep_task`) and the combinations
    (:func:`joint_sweep`), or everything pooled over the tasks; with ``thresholds`` each configuration's
    thresholds too (:attr:`TaskSweep.thresholds`)."""
    base = settings.calibration_settings(seed).threshold_settings()
    streams = {d.task: scores[(d.task, seed)] for d in datasets}
    bases = {d.task: base for d in datasets}
    # a combination normalises its detectors: the swept kinds that have a shape (all of them when pooled)
    kinds = tuple(k for k in settings.sweep.kinds if k in SHAPE_KINDS) or SHAPE_KINDS
    joint = dict(settings=settings.sweep, bases=bases, pooled=settings.pooled, kinds=kinds, thresholds=thresholds)
    parts: list[dict[str, TaskSweep]] = []
    if settings.pooled:
        singles = [c for c in pooled_methods(settings.methods) if c.name != FIPER]
        parts.append(joint_sweep(streams, singles, combines=(), **joint))
        if FIPER in settings.methods:
            fiper = [c for c in pooled_methods(settings.methods) if c.name == FIPER]
            parts.append(joint_sweep(streams, fiper, combines=settings.sweep.combines, **joint))
    else:
        parts.append({task: sweep_task(own, list(settings.methods), settings.sweep, base, thresholds)
                      for task, own in streams.items()})
    if settings.combinations:
        parts.append(joint_sweep(streams, settings.combinations, combines=settings.combines, **joint))
    return {d.task: _joined([part[d.task] for part in parts]) for d in datasets}


def _joined(parts: Sequence[TaskSweep]) -> TaskSweep:
    """One task's configurations of several sweeps, in order (their thresholds where every part kept them)."""
    kept = [part.thresholds for part in parts]
    return TaskSweep([g for part in parts for g in part.groups], np.concatenate([part.alarms for part in parts]),
                     np.concatenate([part.infinite for part in parts]),
                     np.concatenate([part.conformal for part in parts]),
                     None if any(k is None for k in kept) else [t for k in kept if k is not None for t in k])


def sweep_all(
    datasets: Sequence[Dataset],
    scores: dict[tuple[str, int], dict[str, StreamScores]],
    settings: EngineSettings,
    dump: Dump | None = None,
    on_ray: bool = False,
) -> SweepOutcome:
    """Sweep every (task, seed) and evaluate the metrics on the subsets the protocols need; with ``dump``, write
    every (task, seed)'s thresholds and first alarms there as the sweep goes; ``on_ray``: each seed's sweep as a Ray
    task of the cluster joined (:func:`~fiper_ros.evaluation.distributed.sweep_on_ray`), to the same sweep."""
    profile = get_profile(settings.method_settings.profile)
    dt_mode = profile.dt_mode
    subsets: dict[str, list[np.ndarray | None]] = {"all": [None] * len(datasets)}
    held_out: dict[str, list[np.ndarray]] = {"all": [d.held_out_id_successes for d in datasets]}
    if settings.halved:
        splits = [validation_split(d.failed, settings.split_seed) for d in datasets]
        subsets["validation"] = [s[0] for s in splits]
        subsets["report"] = [s[1] for s in splits]
        held_out["report"] = [np.intersect1d(s[1], d.held_out_id_successes) for s, d in zip(splits, datasets)]
    progress = Progress("sweep", len(datasets) * len(settings.seeds), settings.progress)
    groups: list[Group] = []
    metrics: dict[str, list[list[np.ndarray]]] = {name: [[] for _ in datasets] for name in subsets}
    rates: dict[str, list[list[np.ndarray]]] = {name: [[] for _ in datasets] for name in held_out}
    infinite: list[list[np.ndarray]] = [[] for _ in datasets]
    conformal: list[list[np.ndarray]] = [[] for _ in datasets]
    early: dict[str, list[np.ndarray]] = {name: [] for name in ("auroc", "q_auc", "pooled_auroc", "pooled_q_auc")}
    early_seconds = 0.0
    tnr = METRICS.index("tnr")
    by_seed = sweep_on_ray(sweep_seed, datasets, scores, settings, settings.seeds, dump is not None, progress) \
        if on_ray else {}
    for seed in settings.seeds:
        swept_tasks = by_seed.pop(seed) if on_ray else sweep_seed(datasets, scores, settings, seed, dump is not None)
        started = time.perf_counter()
        for name, values in zip(early, early_areas(datasets, scores, settings, seed, swept_tasks[datasets[0].task].groups)):
            early[name].append(values)
        early_seconds += time.perf_counter() - started
        for t, dataset in enumerate(datasets):
            t_max = horizons(dataset, settings.method_settings.profile)
            swept = swept_tasks[dataset.task]
            if dump is not None:
                dump.add(dataset, seed, swept)
            groups = swept.groups
            for name, per_task in subsets.items():
                values = alarm_metrics(swept.alarms, dataset.failed, t_max, dt_mode, per_task[t], profile.metrics_rule)
                values[swept.infinite] = np.nan  # a +inf threshold has no metrics: never averaged
                metrics[name][t].append(values)
            for name, members in held_out.items():
                # every member is a success: the false-alarm rate is 1 - TNR (NaN without members)
                rate = 1.0 - alarm_metrics(swept.alarms, dataset.failed, t_max, dt_mode, members[t])[..., tnr]
                rate[swept.infinite] = np.nan
                rates[name][t].append(rate)
            infinite[t].append(swept.infinite)
            conformal[t].append(swept.conformal)
            if not on_ray:  # (on Ray: as each seed's task finished)
                progress.advance(note=f"{dataset.task} seed {seed}: {len(groups)} configurations")
    progress.close()
    return SweepOutcome(groups, {name: np.stack([np.stack(rows) for rows in per]) for name, per in metrics.items()},
                        np.stack([np.stack(rows) for rows in infinite]),
                        np.stack([np.stack(rows) for rows in conformal]),
                        {name: np.stack([np.stack(rows) for rows in per]) for name, per in rates.items()},
                        {name: [len(m) for m in members] for name, members in held_out.items()},
                        {name: np.stack(values, axis=-2) for name, values in early.items()}, early_seconds)


def task_statistics(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
                    settings: EngineSettings, seed: int) -> list[TaskStatistics]:
    """Per task, the threshold-free statistics of one seed's configurations (:mod:`.early`)."""
    base = settings.calibration_settings(seed).threshold_settings()
    return [TaskStatistics(scores[(d.task, seed)], base, settings.q_auc) for d in datasets]


def early_areas(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
                settings: EngineSettings, seed: int, groups: Sequence[Group]) -> tuple[np.ndarray, ...]:
    """AUROC and q-AUC of every configuration on every task's test rollouts ``[tasks, groups]`` and pooled over the
    tasks ``[groups]`` (one seed)."""
    combinations = settings.combined_detectors()
    maxima = [statistics.peaks(groups, combinations) for statistics in task_statistics(datasets, scores, settings, seed)]
    per_task = [areas(whole, early, d.failed) for (whole, early), d in zip(maxima, datasets)]
    pooled = areas(np.concatenate([m[0] for m in maxima], axis=1), np.concatenate([m[1] for m in maxima], axis=1),
                   np.concatenate([d.failed for d in datasets]))
    return (np.stack([a[0] for a in per_task]), np.stack([a[1] for a in per_task]), pooled[0], pooled[1])


def run_evaluation(
    datasets: Sequence[Dataset], settings: EngineSettings, cache: ScoreCache | None = None, dump: Path | None = None,
    address: str | None = None, cpus: int | None = None,
) -> EvaluationResult:
    """Scores, sweep, metrics and protocols for ``datasets`` (distinct task names); with ``dump`` a directory that
    receives every configuration's thresholds and first alarms (:mod:`fiper_ros.evaluation.dump`); with ``address``
    the scores and the sweep computed on that Ray cluster (:func:`score_all`, :func:`sweep_all`), the results the
    same."""
    check_evaluation(datasets, settings)
    start = time.perf_counter()
    with nullcontext() if address is None else connected(address, cpus):  # one cluster for scores and sweep
        scores, computing = score_all(datasets, settings, cache, address, cpus)
        scored = time.perf_counter()
        writer = None if dump is None else Dump(
            dump, {"profile": settings.method_settings.profile,
                   "calibration_split": settings.method_settings.split_settings(),
                   "deltas": list(settings.sweep.deltas), "or_promise": settings.sweep.or_promise},
            {name: method.streams for name, method in settings.catalogue().items()})
        outcome = sweep_all(datasets, scores, settings, writer, on_ray=address is not None)
        if writer is not None:
            writer.close()
    swept = time.perf_counter()
    protocols: dict[str, ProtocolResult] = {}
    for protocol in settings.protocols:
        selection, report = SUBSETS[protocol]
        if protocol in ON_ONE_SUBSET:  # chosen per task on the rollouts they report on (own or other tasks')
            protocols[protocol] = ON_ONE_SUBSET[protocol](outcome.groups, outcome.metrics[report], settings.columns,
                                                          settings.select_aggregations, outcome.infinite,
                                                          outcome.held_out[report])
            continue
        if protocol == "clean-task":
            protocols[protocol] = run_clean_task(outcome.groups, outcome.metrics[selection], outcome.metrics[report],
                                                 settings.columns, settings.select_aggregations, outcome.infinite,
                                                 outcome.held_out[report])
            continue
        protocols[protocol] = run_protocol(protocol, outcome.groups, outcome.metrics[selection],
                                           outcome.metrics[report], settings.columns, settings.default_window,
                                           settings.default_kind, settings.select_aggregations, outcome.infinite,
                                           outcome.held_out[report])
    selected = time.perf_counter()
    statistics = {seed: task_statistics(datasets, scores, settings, seed) for seed in settings.seeds}
    early = protocol_early(datasets, statistics, settings, protocols)
    early_done = time.perf_counter()
    auto = None if settings.auto is None else run_auto(datasets, scores, settings, settings.auto, outcome)
    if auto is not None:
        auto = replace(auto, early=auto_early(datasets, statistics, settings, auto, outcome.groups))
    timings = {"scores": scored - start, "score_computation": computing, "sweep": swept - scored,
               "early_detection": outcome.early_seconds + early_done - selected,
               **({} if auto is None else {"auto": auto.seconds}),
               **({} if writer is None else {"dump": writer.seconds}), "total": time.perf_counter() - start}
    LOG.info("evaluation: %d configurations x %d deltas, %.1f s", len(outcome.groups), len(settings.sweep.deltas),
             timings["total"])
    first = settings.seeds[0]
    return EvaluationResult(settings, list(datasets), outcome, protocols,
                            {d.task: scores[(d.task, first)] for d in datasets}, timings,
                            cache.hits if cache else 0, cache.misses if cache else 0, early, auto)


def run_auto(datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
             settings: EngineSettings, auto: AutoSettings, outcome: SweepOutcome) -> AutoOutcome:
    """``--auto`` on every task and seed (:func:`~fiper_ros.evaluation.auto.auto_evaluation`; the ``transfer`` rule:
    :func:`~fiper_ros.evaluation.transfer.transfer_evaluation`, its priors from ``outcome``'s metrics on all test
    rollouts), its metrics on all test rollouts and, with a protocol of two halves, on its report half."""
    subsets: dict[str, list[np.ndarray | None]] = {"all": [None] * len(datasets)}
    held_out = {"all": [d.held_out_id_successes for d in datasets]}
    if settings.halved:
        report = [validation_split(d.failed, settings.split_seed)[1] for d in datasets]
        subsets["report"] = list(report)
        held_out["report"] = [np.intersect1d(r, d.held_out_id_successes) for r, d in zip(report, datasets)]
    if auto.rule == TRANSFER:
        return transfer_evaluation(datasets, scores, settings.streams(), outcome.groups, outcome.metrics["all"],
                                   outcome.infinite, members_of(settings.methods, settings.combinations),
                                   settings.method_settings, settings.seeds, settings.sweep.deltas, auto, subsets,
                                   held_out, settings.select_aggregations, settings.prior_top,
                                   settings.statistic, settings.auto_prior, settings.progress, settings.pooled,
                                   settings.sweep.or_promise)
    return auto_evaluation(datasets, scores, settings.streams(), settings.method_settings, settings.seeds,
                           settings.sweep.deltas, auto, subsets, held_out, settings.threads, settings.progress)


def run_prior(result: EvaluationResult, command: str) -> Prior:
    """The prior of every task of the run (:func:`~fiper_ros.evaluation.transfer.ranked_prior`: its best
    ``prior_top`` configurations on all test rollouts, by its :attr:`~EngineSettings.statistic` at its ``promise``);
    ``command``: the command that made it."""
    settings = result.settings
    header = prior_header(result.datasets, settings.method_settings, settings.seeds, settings.sweep.deltas, command,
                          settings.pooled)
    return ranked_prior(result.groups, result.metrics["all"], result.sweep.infinite, result.tasks,
                        members_of(settings.methods, settings.combinations), settings.select_aggregations,
                        settings.prior_top, header, settings.statistic, settings.promise, settings.sweep.or_promise)


def protocol_early(datasets: Sequence[Dataset], statistics: Mapping[int, Sequence[TaskStatistics]],
                   settings: EngineSettings, protocols: dict[str, ProtocolResult]) -> dict[str, dict[str, EarlyDetection]]:
    """Per protocol, every selected configuration's AUROC and q-AUC on the test rollouts the protocol reports on
    (the clean protocol's report half), each task's under its own configuration where it was chosen per task;
    ``statistics[seed][t]`` computes the maxima."""
    combinations = settings.combined_detectors()
    out: dict[str, dict[str, EarlyDetection]] = {}
    for name, protocol in protocols.items():
        report = SUBSETS[name][1]
        subsets = ([validation_split(d.failed, settings.split_seed)[1] for d in datasets] if report == "report"
                   else [None] * len(datasets))
        out[name] = {method: early_detection(statistics,
                                             dict.fromkeys(settings.seeds,
                                                           [chosen.group_of(t) for t in range(len(datasets))]),
                                             [d.failed for d in datasets], subsets, combinations)
                     for method, chosen in protocol.selected.items()}
    return out


def auto_early(datasets: Sequence[Dataset], statistics: Mapping[int, Sequence[TaskStatistics]],
               settings: EngineSettings, auto: AutoOutcome, groups: Sequence[Group]) -> EarlyDetection | None:
    """``--auto``'s AUROC and q-AUC on all test rollouts: per seed each task's choice at the delta it is shown at
    (:func:`~fiper_ros.evaluation.transfer.chosen_groups`), measured as the sweep's configuration it is; ``None`` when
    some choice is not one of them."""
    chosen = chosen_groups(auto, groups, members_of(settings.methods, settings.combinations), settings.seeds)
    if chosen is None:
        return None
    return early_detection(statistics, chosen, [d.failed for d in datasets], [None] * len(datasets),
                           settings.combined_detectors())
