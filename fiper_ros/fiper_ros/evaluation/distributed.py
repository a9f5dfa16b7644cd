"""The scores and the sweep of an evaluation as Ray tasks (``fiper evaluate --ray [ADDRESS]``): one task per (task,
seed, stream) the cache does not hold, each running :func:`~fiper_ros.evaluation.scoring.score_stream` (the function
of the single-process run), then one task per seed running the single-process run's sweep of that seed (every
configuration's threshold fits and first alarms, :func:`~fiper_ros.evaluation.engine.sweep_seed`), on a local
instance or an existing cluster (:mod:`fiper_ros.cluster`).

Every dataset and the method settings go once to the cluster's object store; the driver reads and writes the score
cache and gathers the results by key, so the scores, and every number computed from them, are the single-process
run's. A task whose data the stream cannot serve returns its :class:`~fiper_ros.evaluation.data.DatasetError`,
which the driver raises as the single-process run would; any other failure is one line naming the task
(:class:`~fiper_ros.cluster.ClusterError`).
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Sequence
from typing import Any, Protocol, TypeVar

from fiper_ros.cluster import LOCAL, TaskPool, connected
from fiper_ros.evaluation.cache import RolloutScores, ScoreCache, StreamScores
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.progress import Progress
from fiper_ros.evaluation.scoring import score_stream, separated_streams, stream_keys

#: A score task: (task, seed, stream).
Key = tuple[str, int, str]
#: What one seed's sweep gives.
Swept = TypeVar("Swept")
#: The settings one seed's sweep reads (the engine's): only carried, to the object store and into the sweep.
Settings = TypeVar("Settings")
#: :data:`Settings` and :data:`Swept` as :class:`SeedSweep` takes and gives them (a parameter, a result).
SettingsTaken = TypeVar("SettingsTaken", contravariant=True)
SweptGiven = TypeVar("SweptGiven", covariant=True)


class SeedSweep(Protocol[SettingsTaken, SweptGiven]):
    """The single-process run's sweep of one seed (:func:`~fiper_ros.evaluation.engine.sweep_seed`), as
    :func:`sweep_on_ray` runs it: what a seed's sweep takes is all this module knows of the engine's settings."""

    def __call__(self, datasets: Sequence[Dataset], scores: dict[tuple[str, int], dict[str, StreamScores]],
                 settings: SettingsTaken, seed: int, thresholds: bool) -> SweptGiven:
        """Every configuration of ``seed`` (with their thresholds if ``thresholds``)."""


def stream_task(shared: list[Any], stream: str, seed: int, threads: int) -> tuple[RolloutScores, float] | DatasetError:
    """:func:`score_stream` on a Ray worker (``shared``: the references of the dataset and the method settings in
    the object store, in a list so that Ray hands over the references); a :class:`DatasetError` is returned, for
    the driver to raise."""
    import ray  # noqa: PLC0415 - the worker of a Ray task has it

    dataset, settings = ray.get(shared)
    try:
        return score_stream(dataset, stream, settings, seed, threads)
    except DatasetError as error:
        return error


def score_on_ray(datasets: Sequence[Dataset], streams: Sequence[str], settings: MethodSettings, seeds: Sequence[int],
                 cache: ScoreCache | None, threads: int, progress: Progress, address: str = LOCAL,
                 cpus: int | None = None) -> tuple[dict[tuple[str, int], dict[str, StreamScores]], float]:
    """Scores of every (task, seed) as :func:`~fiper_ros.evaluation.engine.score_all` computes them, the streams the
    cache does not hold as Ray tasks of the cluster at ``address`` (``cpus``: of a local instance); returns them
    and the seconds the tasks spent computing. ``progress`` advances once per (task, seed).

    Raises:
        DatasetError: A task's data cannot be scored (the single-process run's message).
        ClusterError: The cluster cannot be reached, or a task failed otherwise (one line).
    """
    units = [(d, seed) for d in datasets for seed in seeds]
    keys = {(d.task, seed): {} if cache is None else stream_keys(d, streams, settings, seed) for d, seed in units}
    raw: dict[tuple[str, int], dict[str, RolloutScores]] = {unit: {} for unit in keys}
    missing: dict[tuple[str, int], list[str]] = {unit: [] for unit in keys}
    # a key an earlier (task, seed) misses is computed once and read back from the cache, as the serial run does
    later: dict[tuple[str, int], list[str]] = {unit: [] for unit in keys}
    first: dict[str, tuple[str, int]] = {}  # cache key -> the (task, seed) whose task computes it
    for unit, own in keys.items():
        for stream in streams:
            if own and own[stream] in first:
                later[unit].append(stream)
                continue
            found = None if cache is None else cache.get(own[stream])
            if found is not None:
                raw[unit][stream] = found
                continue
            missing[unit].append(stream)
            if own:
                first[own[stream]] = unit
    left = Counter({unit: len(names) for unit, names in missing.items()})
    for unit in [u for u in raw if not left[u]]:
        progress.advance(note=f"{unit[0]} seed {unit[1]} (cached)")
    computing = 0.0
    if sum(left.values()):  # no cluster for a run the cache serves
        computing = _compute(datasets, settings, seeds, threads, missing, raw, left, progress, address, cpus)
    out: dict[tuple[str, int], dict[str, StreamScores]] = {}
    for dataset, seed in units:
        unit = (dataset.task, seed)
        for stream in later[unit]:  # put by an earlier (task, seed)'s separated_streams
            found = None if cache is None else cache.get(keys[unit][stream])
            raw[unit][stream] = found if found is not None else raw[first[keys[unit][stream]]][stream]
        computed = {s: keys[unit][s] for s in missing[unit] if keys[unit]}
        out[unit] = separated_streams(dataset, streams, settings, seed, raw[unit], computed, cache)
    return out, computing


def _compute(datasets: Sequence[Dataset], settings: MethodSettings, seeds: Sequence[int], threads: int,
             missing: dict[tuple[str, int], list[str]], raw: dict[tuple[str, int], dict[str, RolloutScores]],
             left: Counter[tuple[str, int]], progress: Progress, address: str, cpus: int | None) -> float:
    """The ``missing`` streams of every (task, seed) as Ray tasks, their scores into ``raw``; returns the seconds
    the tasks spent."""
    computing = 0.0
    with connected(address, cpus):
        import ray  # noqa: PLC0415 - after connected, which sets Ray's environment

        shared_settings = ray.put(settings)
        tasks: TaskPool[Key] = TaskPool(stream_task, lambda key: f"task {key[0]!r} seed {key[1]} {key[2]}")
        for dataset in datasets:
            shared = [ray.put(dataset), shared_settings]
            for seed in seeds:
                for stream in missing[(dataset.task, seed)]:
                    tasks.submit((dataset.task, seed, stream), shared, stream, seed, threads)
        try:
            for (task, seed, stream), value in tasks.completed():
                if isinstance(value, DatasetError):
                    raise value
                raw[(task, seed)][stream], seconds = value
                computing += seconds
                left[(task, seed)] -= 1
                if not left[(task, seed)]:
                    progress.advance(note=f"{task} seed {seed} | ray: {tasks.status()}")
        finally:
            tasks.close()
    return computing


def seed_task(sweep: SeedSweep[Settings, Swept], shared: list[Any], seed: int, thresholds: bool) -> Swept:
    """``sweep`` (the single-process run's sweep of one seed) on a Ray worker; ``shared``: the references of the
    datasets, of the seed's scores and of the engine settings in the object store."""
    import ray  # noqa: PLC0415 - the worker of a Ray task has it

    datasets, scores, settings = ray.get(shared)
    return sweep(datasets, scores, settings, seed, thresholds)


def sweep_on_ray(sweep: SeedSweep[Settings, Swept], datasets: Sequence[Dataset],
                 scores: dict[tuple[str, int], dict[str, StreamScores]], settings: Settings, seeds: Sequence[int],
                 thresholds: bool, progress: Progress) -> dict[int, Swept]:
    """``sweep(datasets, scores, settings, seed, thresholds)`` of every seed as one Ray task each, on the cluster
    joined (inside :func:`~fiper_ros.cluster.connected`): the datasets and the settings go to the object store once,
    each seed's scores once. ``progress`` advances once per (task, seed) as each seed's sweep finishes.

    Raises:
        ClusterError: A sweep failed (one line naming its seed).
    """
    import ray  # noqa: PLC0415 - inside connected, which set Ray's environment

    shared_datasets, shared_settings = ray.put(list(datasets)), ray.put(settings)
    tasks: TaskPool[int] = TaskPool(seed_task, lambda seed: f"the sweep of seed {seed}")
    for seed in seeds:
        own = {(d.task, seed): scores[(d.task, seed)] for d in datasets}
        tasks.submit(seed, sweep, [shared_datasets, ray.put(own), shared_settings], seed, thresholds)
    swept: dict[int, Swept] = {}
    try:
        for seed, value in tasks.completed():
            swept[seed] = value
            for dataset in datasets:
                progress.advance(note=f"{dataset.task} seed {seed} | ray: {tasks.status()}")
    finally:
        tasks.close()
    return swept
