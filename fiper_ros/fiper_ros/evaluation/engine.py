"""The evaluation run: scores (cached) -> sweep -> metrics -> protocols, for several tasks and seeds."""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.compat import get_profile
from fiper_ros.evaluation.cache import ScoreCache, StreamScores
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.methods import METHODS, MethodSettings, streams_of
from fiper_ros.evaluation.progress import Progress
from fiper_ros.evaluation.protocol import PROTOCOLS, ProtocolResult, alarm_metrics, run_protocol, validation_split
from fiper_ros.evaluation.scoring import compute_streams
from fiper_ros.evaluation.sweep import Group, SweepSettings, sweep_task

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class EngineSettings:
    """Everything an evaluation run depends on besides the data.

    Attributes:
        methods: Method names (:data:`fiper_ros.evaluation.methods.METHODS`), in table order.
        seeds: Seeds of the learned scores and of the CP band split.
        sweep: Windows, deltas, threshold kinds, FIPER pairs and combines.
        method_settings: Hyperparameters of every score stream (and the profile).
        protocols: Some of :data:`fiper_ros.evaluation.protocol.PROTOCOLS`.
        split_seed: Seed of the clean protocol's validation/report split.
        default_window, default_kind: The fixed default configuration.
        select_aggregations: Aggregations a method's configuration may be selected from.
        threads: torch threads while scores are computed.
        progress: Draw progress lines on stderr.
    """

    methods: tuple[str, ...] = tuple(METHODS)
    seeds: tuple[int, ...] = (0,)
    sweep: SweepSettings = field(default_factory=SweepSettings)
    method_settings: MethodSettings = field(default_factory=MethodSettings)
    protocols: tuple[str, ...] = ("paper",)
    split_seed: int = 0
    default_window: int = 5
    default_kind: str = "cp_band"
    select_aggregations: tuple[str, ...] = ("window",)
    threads: int = 1
    progress: bool = True

    def __post_init__(self) -> None:
        streams_of(list(self.methods))
        if any(p not in PROTOCOLS for p in self.protocols):
            raise ValueError(f"protocols must be among {PROTOCOLS}, got {self.protocols}")
        if not self.seeds:
            raise ValueError("at least one seed is needed")

    def calibration_settings(self, seed: int) -> CalibrationSettings:
        """The core calibration settings whose threshold rules the sweep uses (profile, seed)."""
        return CalibrationSettings(profile=self.method_settings.profile, seed=seed)


@dataclass
class EvaluationResult:
    """All numbers of one run.

    ``metrics[subset]`` is ``[tasks, seeds, groups, deltas, 5]`` for subsets ``"all"`` and, with the
    clean protocol, ``"validation"`` and ``"report"``. ``streams`` keeps the first seed's scores for plots.
    """

    settings: EngineSettings
    datasets: list[Dataset]
    groups: list[Group]
    metrics: dict[str, np.ndarray]
    protocols: dict[str, ProtocolResult]
    streams: dict[str, dict[str, StreamScores]]
    timings: dict[str, float]
    cache_hits: int = 0
    cache_misses: int = 0

    @property
    def tasks(self) -> list[str]:
        """Task names in input order."""
        return [d.task for d in self.datasets]


def horizons(dataset: Dataset, profile: str) -> np.ndarray | int:
    """``T`` of the DT formula: each rollout's length (paper) or ``T_max`` over both splits (reference)."""
    return dataset.lengths if get_profile(profile).dt_mode == "paper" else dataset.max_length


def score_all(
    datasets: Sequence[Dataset], settings: EngineSettings, cache: ScoreCache | None
) -> tuple[dict[tuple[str, int], dict[str, StreamScores]], float]:
    """Scores of every (task, seed); returns them and the seconds spent computing (not reading) them."""
    streams = streams_of(list(settings.methods))
    progress = Progress("scores", len(datasets) * len(settings.seeds), settings.progress)
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


def sweep_all(
    datasets: Sequence[Dataset],
    scores: dict[tuple[str, int], dict[str, StreamScores]],
    settings: EngineSettings,
) -> tuple[list[Group], dict[str, np.ndarray]]:
    """Sweep every (task, seed) and evaluate the metrics on the subsets the protocols need."""
    dt_mode = get_profile(settings.method_settings.profile).dt_mode
    subsets: dict[str, list[np.ndarray | None]] = {"all": [None] * len(datasets)}
    if "clean" in settings.protocols:
        splits = [validation_split(d.failed, settings.split_seed) for d in datasets]
        subsets["validation"] = [s[0] for s in splits]
        subsets["report"] = [s[1] for s in splits]
    progress = Progress("sweep", len(datasets) * len(settings.seeds), settings.progress)
    groups: list[Group] = []
    metrics: dict[str, list[list[np.ndarray]]] = {name: [] for name in subsets}
    for t, dataset in enumerate(datasets):
        rows: dict[str, list[np.ndarray]] = {name: [] for name in subsets}
        for seed in settings.seeds:
            base = settings.calibration_settings(seed).threshold_settings()
            groups, alarms = sweep_task(scores[(dataset.task, seed)], list(settings.methods), settings.sweep, base)
            for name, per_task in subsets.items():
                rows[name].append(alarm_metrics(alarms, dataset.failed, horizons(dataset, settings.method_settings.profile),
                                                dt_mode, per_task[t]))
            progress.advance(note=f"{dataset.task} seed {seed}: {len(groups)} configurations")
        for name in subsets:
            metrics[name].append(np.stack(rows[name]))
    progress.close()
    return groups, {name: np.stack(per_task) for name, per_task in metrics.items()}


def run_evaluation(
    datasets: Sequence[Dataset], settings: EngineSettings, cache: ScoreCache | None = None
) -> EvaluationResult:
    """Scores, sweep, metrics and protocols for ``datasets`` (distinct task names)."""
    tasks = [d.task for d in datasets]
    if len(set(tasks)) != len(tasks):
        raise ValueError(f"task names must be distinct, got {tasks}")
    start = time.perf_counter()
    scores, computing = score_all(datasets, settings, cache)
    scored = time.perf_counter()
    groups, metrics = sweep_all(datasets, scores, settings)
    swept = time.perf_counter()
    protocols: dict[str, ProtocolResult] = {}
    for protocol in settings.protocols:
        selection, report = ("all", "all") if protocol == "paper" else ("validation", "report")
        protocols[protocol] = run_protocol(protocol, groups, metrics[selection], metrics[report], settings.methods,
                                           settings.default_window, settings.default_kind,
                                           settings.select_aggregations)
    timings = {"scores": scored - start, "score_computation": computing, "sweep": swept - scored,
               "total": time.perf_counter() - start}
    LOG.info("evaluation: %d configurations x %d deltas, %.1f s", len(groups), len(settings.sweep.deltas),
             timings["total"])
    first = settings.seeds[0]
    return EvaluationResult(settings, list(datasets), groups, metrics, protocols,
                            {d.task: scores[(d.task, first)] for d in datasets}, timings,
                            cache.hits if cache else 0, cache.misses if cache else 0)
