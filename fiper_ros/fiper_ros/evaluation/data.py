"""Evaluation datasets: a task name with its calibration and test rollouts.

A dataset is read from one or more ``.npz`` files written by
:meth:`fiper_ros.core.rollout.RolloutSet.save_npz` (or directories of them), or from folders of bags; the
calibration and test splits of all files are concatenated in file-name order. All rollouts of a dataset have one
layout (:func:`layout`): the score models are fitted for one. Data of several tasks (``fiper convert generic`` of
many tasks) gives one dataset per task, named by the task (:func:`load_datasets`); bags without a split
(``custom_data`` split empty) are split per task as ``fiper convert`` splits logs without one
(:mod:`fiper_ros.core.data_split`).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.core.data_split import (DEFAULT_FRACTION, DEFAULT_SEED, NO_SPLIT, SPLITS, DataSplitError, TaskSplit,
                                       split_by_task)
from fiper_ros.core.rollout import Rollout, RolloutError, RolloutSet, successful
from fiper_ros.evaluation.errors import EvaluationError

#: The four rollout categories of the paper's Fig. 3.
CATEGORIES = ("Success-ID", "Success-OOD", "Fail-ID", "Fail-OOD")


class DatasetError(EvaluationError):
    """A dataset cannot be read or is unusable for evaluation."""


@dataclass
class Dataset:
    """One task's calibration rollouts (successes are used) and labelled test rollouts."""

    task: str
    calibration: list[Rollout]
    test: list[Rollout]

    def __post_init__(self) -> None:
        if not successful(self.calibration):
            raise DatasetError(f"task {self.task!r}: no successful calibration rollouts")
        unknown = [r.rollout_id for r in self.test if r.success is None]
        if unknown:
            raise DatasetError(f"task {self.task!r}: test rollouts without an outcome: {unknown[:3]}")
        if not self.test:
            raise DatasetError(f"task {self.task!r}: no test rollouts")

    @property
    def has_actions(self) -> bool:
        """Whether every rollout holds its action batches (else the data is observation-only for the methods)."""
        return all(r.has_actions for r in (*self.calibration, *self.test))

    @property
    def action_space(self) -> str:
        """The policy's action space (every rollout of a task shares it)."""
        return self.calibration[0].action_space

    @property
    def calibration_successes(self) -> list[Rollout]:
        """The calibration data ``D_c`` (Sec. 4.3): successful calibration rollouts."""
        return successful(self.calibration)

    @property
    def failed(self) -> np.ndarray:
        """Per test rollout, whether it failed (a positive)."""
        return np.array([bool(r.failed) for r in self.test])

    @property
    def held_out_id_successes(self) -> np.ndarray:
        """Indices of the test rollouts that succeeded in the ID scenario: new successes exchangeable with
        the calibration successes, on which a threshold's false-alarm rate is set beside delta (Prop. 1)."""
        return np.array([i for i, r in enumerate(self.test) if r.success and not r.is_ood], dtype=int)

    @property
    def lengths(self) -> np.ndarray:
        """Per test rollout, ``T``."""
        return np.array([r.length for r in self.test])

    @property
    def max_length(self) -> int:
        """Longest rollout over calibration and test (``T_max`` of the reference DT)."""
        return max(r.length for r in (*self.calibration, *self.test))

    @property
    def categories(self) -> list[str]:
        """Per test rollout, one of :data:`CATEGORIES`."""
        return [f"{'Success' if r.success else 'Fail'}-{'OOD' if r.is_ood else 'ID'}" for r in self.test]

    def digest(self) -> str:
        """SHA-256 over every rollout's arrays, outcome, scenario and layout (the score-cache key)."""
        digest = hashlib.sha256(self.task.encode())
        for split, rollouts in (("calibration", self.calibration), ("test", self.test)):
            for rollout in rollouts:
                actions = rollout.actions
                head = (split, rollout.rollout_id, rollout.scenario, rollout.success, rollout.exec_steps,
                        rollout.action_space, rollout.embeddings.shape, None if actions is None else actions.shape)
                digest.update(repr(head).encode())
                digest.update(rollout.embeddings.tobytes())
                if actions is not None:
                    digest.update(actions.tobytes())
                for key in sorted(rollout.metadata):
                    value = rollout.metadata[key]
                    if isinstance(value, np.ndarray):
                        digest.update(key.encode())
                        digest.update(np.ascontiguousarray(value).tobytes())
                for name in sorted(rollout.signals):  # none: the digest of data without signals, as before them
                    digest.update(f"signal {name}".encode())
                    digest.update(rollout.signals[name].tobytes())
        return digest.hexdigest()


def layout(rollout: Rollout) -> tuple[tuple[str, object], ...]:
    """What the score models of a task are fitted for: E, H, D, h and the action space of a rollout."""
    horizon, dims = (None, None) if rollout.actions is None else rollout.actions.shape[2:]
    return (("E", rollout.embeddings.shape[1]), ("H", horizon), ("D", dims), ("h", rollout.exec_steps),
            ("action space", rollout.action_space))


def check_layout(sources: Sequence[tuple[Rollout, str]]) -> None:
    """Refuse rollouts (each with the file or bag it came from) of more than one :func:`layout`, naming the
    first that differs and the first rollout."""
    if not sources:
        return
    first, origin = sources[0]
    expected = layout(first)
    for rollout, source in sources[1:]:
        got = layout(rollout)
        if got != expected:
            name = next(key for (key, value), (_, want) in zip(got, expected) if value != want)
            raise DatasetError(f"{source}: rollout {rollout.rollout_id!r} has {name} = {dict(got)[name]}, rollout "
                               f"{first.rollout_id!r} of {origin} {name} = {dict(expected)[name]}: one task's "
                               "rollouts share one layout")


def _npz_files(path: Path) -> list[Path]:
    if path.is_dir():
        files = sorted(path.glob("*.npz"))
        if not files:
            raise DatasetError(f"no .npz rollout files and no bags in {path}")
        return files
    if not path.is_file():
        raise DatasetError(f"rollout file or directory not found: {path}")
    return [path]


#: Rollouts (each with the file or bag it came from) by split: ``calibration``, ``test`` and ``NO_SPLIT`` (a bag
#: whose ``custom_data`` gives none).
Sources = dict[str, list[tuple[Rollout, str]]]


def _bag_split(path: Path, strict: bool, sources: Sources) -> None:
    """Add the rollouts of the bags at ``path`` with their bag to ``sources``, by each bag's ``custom_data`` split
    (empty: ``NO_SPLIT``; ``strict``: refuse an unfinished bag instead of reading it up to its last complete
    chunk)."""
    from fiper_ros.bagio.errors import BagError  # noqa: PLC0415 - bags need the ROS message build
    from fiper_ros.bagio.reader import BagReader, find_bags  # noqa: PLC0415
    from fiper_ros.bagio.rollout_bags import read_rollouts  # noqa: PLC0415

    try:
        for bag in find_bags([path], strict=strict):
            with BagReader(bag) as reader:
                split = reader.info.split
            if split not in (*SPLITS, NO_SPLIT):
                raise DatasetError(f"{bag}: custom_data split is {split!r}; expected 'calibration', 'test' or none")
            sources[split].extend((r, str(bag)) for r in read_rollouts(bag))
    except BagError as error:
        raise DatasetError(str(error)) from error


def _is_bag_input(path: Path) -> bool:
    """A directory of bags (MCAP data or bag metadata below it) rather than of ``.npz`` rollout sets."""
    return path.is_dir() and not any(path.glob("*.npz")) and any(
        any(path.rglob(pattern)) for pattern in ("metadata.yaml", "*.mcap"))


def _read(paths: Sequence[str | Path], strict: bool) -> Sources:
    """The rollouts at ``paths`` (``.npz`` files, folders of them, or bag folders) by split, each with its source."""
    sources: Sources = {split: [] for split in (*SPLITS, NO_SPLIT)}
    for path in map(Path, paths):
        if _is_bag_input(path):
            _bag_split(path, strict, sources)
            continue
        for file in _npz_files(path):
            try:
                rollouts = RolloutSet.load_npz(file)
            except RolloutError as error:
                # the rollout's own checks (shapes, NaN) do not know the file: name it
                text = str(error)
                raise DatasetError(text if text.startswith(str(file)) else f"{file}: {text}") from error
            sources["calibration"].extend((r, str(file)) for r in rollouts.calibration)
            sources["test"].extend((r, str(file)) for r in rollouts.test)
    return sources


def _draw(sources: Sources, fraction: float, seed: int) -> dict[str, TaskSplit]:
    """Split the :data:`NO_SPLIT` rollouts of ``sources`` per task into its calibration and test lists; the drawn
    split per task. Data with and without a split is refused."""
    unsplit = sources.pop(NO_SPLIT)
    if not unsplit:
        return {}
    given = next((source for split in SPLITS for _, source in sources[split]), None)
    if given is not None:
        raise DatasetError(f"{unsplit[0][1]}: no split (custom_data split empty), while {given} has one: give data "
                           "with a split, or all without one (then a seeded --calibration-fraction of each task's "
                           "successes is calibration)")
    try:
        drawn = split_by_task(unsplit, lambda item: item[0], fraction, seed)
    except DataSplitError as error:
        raise DatasetError(str(error)) from error
    for part in drawn.values():
        sources["calibration"] += part.calibration
        sources["test"] += part.test
    return {task: part.split for task, part in drawn.items()}


def load_datasets(name: str, paths: Sequence[str | Path], strict: bool = True, fraction: float = DEFAULT_FRACTION,
                  seed: int = DEFAULT_SEED) -> tuple[list[Dataset], dict[str, TaskSplit]]:
    """Read the rollouts at ``paths`` (``.npz`` files, folders of them, or bag folders) into one :class:`Dataset`
    per task: named ``name`` when they are of one task, else each by its task (in name order). Bags are split by
    their ``custom_data`` split (``fiper convert`` writes it); bags without one are split per task by
    :func:`fiper_ros.core.data_split.split_by_task` (``fraction``, ``seed``), which is returned (empty when the data
    gave the split). An unfinished bag is refused with ``strict``, else read up to its last complete chunk with a
    warning; a task's rollouts of more than one layout are refused (:func:`check_layout`)."""
    sources = _read(paths, strict)
    drawn = _draw(sources, fraction, seed)
    tasks = sorted({rollout.task for items in sources.values() for rollout, _ in items})
    if len(tasks) > 1 and "" in tasks:
        raise DatasetError(f"{name}: rollouts without a task name beside those of tasks {', '.join(tasks[1:])}: "
                           "one dataset per task needs every rollout's task")
    datasets = []
    for task in tasks:
        calibration, test = ([(r, s) for r, s in sources[split] if r.task == task] for split in SPLITS)
        check_layout([*calibration, *test])
        datasets.append(Dataset(name if len(tasks) == 1 else task, [r for r, _ in calibration], [r for r, _ in test]))
    if not datasets:
        raise DatasetError(f"{name}: no rollouts in {', '.join(map(str, paths))}")
    return datasets, drawn


def load_dataset(task: str, paths: Sequence[str | Path], strict: bool = True) -> Dataset:
    """The one :class:`Dataset` of :func:`load_datasets` (rollouts with their split, of one task)."""
    datasets, _ = load_datasets(task, paths, strict)
    if len(datasets) > 1:
        raise DatasetError(f"{task}: rollouts of {len(datasets)} tasks ({', '.join(d.task for d in datasets)}): "
                           "one dataset per task (load_datasets)")
    return datasets[0]
