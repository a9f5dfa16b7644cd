"""Evaluation datasets: a task name with its calibration and test rollouts.

A dataset is read from one or more ``.npz`` files written by
:meth:`fiper_ros.core.rollout.RolloutSet.save_npz` (or directories of them); the calibration and
test splits of all files are concatenated in file-name order. All rollouts of a dataset have one layout
(:func:`layout`): the score models are fitted for one.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.core.rollout import Rollout, RolloutError, RolloutSet, successful

#: The four rollout categories of the paper's Fig. 3.
CATEGORIES = ("Success-ID", "Success-OOD", "Fail-ID", "Fail-OOD")


class DatasetError(ValueError):
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


def _bag_split(path: Path, strict: bool) -> tuple[list[tuple[Rollout, str]], list[tuple[Rollout, str]]]:
    """The rollouts of the bags at ``path`` with their bag, split by each bag's ``custom_data`` split
    (``strict``: refuse an unfinished bag instead of reading it up to its last complete chunk)."""
    from fiper_ros.bagio.errors import BagError  # noqa: PLC0415 - bags need the ROS message build
    from fiper_ros.bagio.reader import BagReader, find_bags  # noqa: PLC0415
    from fiper_ros.bagio.rollout_bags import read_rollouts  # noqa: PLC0415

    calibration: list[tuple[Rollout, str]] = []
    test: list[tuple[Rollout, str]] = []
    try:
        for bag in find_bags([path], strict=strict, command="evaluate"):
            with BagReader(bag) as reader:
                split = reader.info.split
            if split not in ("calibration", "test"):
                raise DatasetError(f"{bag}: custom_data split is {split!r}; expected 'calibration' or 'test'")
            (calibration if split == "calibration" else test).extend((r, str(bag)) for r in read_rollouts(bag))
    except BagError as error:
        raise DatasetError(str(error)) from error
    return calibration, test


def _is_bag_input(path: Path) -> bool:
    """A directory of bags (MCAP data or bag metadata below it) rather than of ``.npz`` rollout sets."""
    return path.is_dir() and not any(path.glob("*.npz")) and any(
        any(path.rglob(pattern)) for pattern in ("metadata.yaml", "*.mcap"))


def load_dataset(task: str, paths: Sequence[str | Path], strict: bool = True) -> Dataset:
    """Read the rollout sets at ``paths`` (``.npz`` files, folders of them, or bag folders) into one
    :class:`Dataset`. Bags are split by their ``custom_data`` split (``fiper convert`` writes it); an
    unfinished bag is refused with ``strict``, else read up to its last complete chunk with a warning; rollouts
    of more than one layout are refused (:func:`check_layout`)."""
    calibration: list[tuple[Rollout, str]] = []
    test: list[tuple[Rollout, str]] = []
    for path in map(Path, paths):
        if _is_bag_input(path):
            cal, tst = _bag_split(path, strict)
            calibration.extend(cal)
            test.extend(tst)
            continue
        for file in _npz_files(path):
            try:
                rollouts = RolloutSet.load_npz(file)
            except RolloutError as error:
                # the rollout's own checks (shapes, NaN) do not know the file: name it
                text = str(error)
                raise DatasetError(text if text.startswith(str(file)) else f"{file}: {text}") from error
            calibration.extend((r, str(file)) for r in rollouts.calibration)
            test.extend((r, str(file)) for r in rollouts.test)
    check_layout([*calibration, *test])
    return Dataset(task, [r for r, _ in calibration], [r for r, _ in test])
