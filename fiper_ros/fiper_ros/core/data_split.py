"""Calibration and test rollouts of data that comes without a split (users' logs: outcomes, many tasks, no split).

Per task, a seeded fraction ``F`` of the task's successes is its calibration set ``D_c`` (Sec. 4.3); every other
rollout of the task (its other successes, all its failures, any without an outcome) is test data. The draw is
stratified per task and seeded by the seed and the task's name alone, so a task's split does not depend on the
other tasks converted or evaluated with it, nor on where its rollouts sit among theirs: for a seed, the same
rollouts of a task (in the same order) always give the same split. ``fiper convert generic`` and ``fiper evaluate``
draw it with the same rule (docs/bags.md, "No split given").

The calibration set must serve the default split-conformal calibration (:func:`fiper_ros.core.calibration.
split_successes` with the default :class:`~fiper_ros.core.calibration.CalibrationSettings`: a ``conformal_fraction``
of the calibration successes for the conformal quantiles, at least ``min_rollouts`` left to fit the score models).
A fraction that leaves a task less is refused, naming the task, its successes and the smallest fraction that
would do (:class:`DataSplitError`).
"""
from __future__ import annotations

import zlib
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Generic, TypeVar

import numpy as np

from fiper_ros.core.calibration import CalibrationSettings, split_successes
from fiper_ros.core.errors import CoreError
from fiper_ros.core.rollout import Rollout

#: The two splits of an evaluation's data, and the "split" of rollouts whose data gives none.
SPLITS = ("calibration", "test")
NO_SPLIT = ""
#: Default fraction of each task's successes drawn into its calibration set.
DEFAULT_FRACTION = 0.5
#: Default seed of the draw.
DEFAULT_SEED = 0
#: Step of the fractions a refusal suggests.
FRACTION_STEP = 0.01
#: What is split: a rollout with whatever the caller keeps beside it.
Item = TypeVar("Item")


class DataSplitError(CoreError):
    """A fraction that is no fraction, or that leaves a task too few calibration successes."""


@dataclass(frozen=True)
class TaskSplit:
    """One task's drawn split, by index into its rollouts (in the order given).

    Attributes:
        task: The task.
        calibration: Indices of the successes drawn into the calibration set (ascending).
        test: Indices of every other rollout (ascending).
        successes: How many of the task's rollouts succeeded.
        failures: How many failed (the rest have no outcome).
    """

    task: str
    calibration: tuple[int, ...]
    test: tuple[int, ...]
    successes: int
    failures: int

    def summary(self) -> str:
        """One line: the task's rollouts and what went where."""
        unknown = len(self.calibration) + len(self.test) - self.successes - self.failures
        other = f", {unknown} without an outcome" if unknown else ""
        return (f"{self.task}: {len(self.calibration) + len(self.test)} rollouts ({self.successes} successes, "
                f"{self.failures} failures{other}): calibration {len(self.calibration)} successes, test "
                f"{self.successes - len(self.calibration)} successes and {self.failures} failures{other}")


def calibration_count(successes: int, fraction: float) -> int:
    """How many of ``successes`` successes a ``fraction`` draws into the calibration set (rounded as
    :func:`~fiper_ros.core.calibration.split_successes` rounds its conformal fraction)."""
    return round(fraction * successes)


def serves_calibration(count: int) -> bool:
    """Whether ``count`` calibration successes give the default split-conformal calibration at least one conformal
    success and ``min_rollouts`` to fit the score models."""
    settings = CalibrationSettings()
    if count < settings.min_rollouts + 1:
        return False
    split = split_successes(count, settings)
    return len(split.conformal) >= 1 and len(split.fit) >= settings.min_rollouts


def fewest_calibration_successes() -> int:
    """The fewest calibration successes that :func:`serves_calibration`."""
    count = CalibrationSettings().min_rollouts + 1
    while not serves_calibration(count):
        count += 1
    return count


def smallest_fraction(successes: int) -> float | None:
    """The smallest fraction (a multiple of :data:`FRACTION_STEP` below 1) whose draw of ``successes`` successes
    :func:`serves_calibration`; ``None`` if none does."""
    steps = round(1 / FRACTION_STEP)
    for step in range(1, steps):
        if serves_calibration(calibration_count(successes, step / steps)):
            return step / steps
    return None


def check_fraction(fraction: float) -> None:
    """Refuse a fraction outside (0, 1)."""
    if not 0.0 < fraction < 1.0:
        raise DataSplitError(f"calibration fraction must be in (0, 1), got {fraction:g}")


def check_draw(fraction: float, seed: int, options: tuple[str, str]) -> None:
    """Refuse a fraction outside (0, 1) or a negative seed, naming the ``options`` (fraction, seed) that gave them."""
    try:
        check_fraction(fraction)
    except DataSplitError as error:
        raise DataSplitError(f"{options[0]}: {error}") from error
    if seed < 0:
        raise DataSplitError(f"{options[1]}: the seed must be >= 0, got {seed}")


def describe(fraction: float, seed: int) -> str:
    """The rule of a drawn split in words (stored with what it split, e.g. a bag's ``custom_data`` ``split_rule``)."""
    return (f"drawn: per task, calibration fraction {fraction:g} of its successes (seed {seed}), every other rollout "
            "test")


def _task_seed(task: str) -> int:
    """The task's part of the draw's seed: a CRC-32 of its name (stable across runs and platforms)."""
    return zlib.crc32(task.encode())


def split_task(task: str, outcomes: Sequence[bool | None], fraction: float, seed: int) -> TaskSplit:
    """The split of one task's rollouts, given their outcomes in order (``True`` success).

    The successes are permuted by a generator seeded with ``[seed, crc32(task)]``; the first
    :func:`calibration_count` of them are the calibration set. Refused (:class:`DataSplitError`) when that set does
    not :func:`serves_calibration`.
    """
    check_fraction(fraction)
    successes = [i for i, outcome in enumerate(outcomes) if outcome is True]
    count = calibration_count(len(successes), fraction)
    if not serves_calibration(count):
        need = fewest_calibration_successes()
        parts = split_successes(need, CalibrationSettings())
        why = (f"the default split-conformal calibration needs at least {need} ({len(parts.conformal)} conformal, "
               f"{len(parts.fit)} to fit the score models)")
        better = smallest_fraction(len(successes))
        advice = (f"a fraction of {better:g} or more would do" if better is not None
                  else f"no fraction below 1 gives {need}: collect more successes")
        raise DataSplitError(f"task {task!r}: calibration fraction {fraction:g} draws {count} of its "
                             f"{len(successes)} successes; {why}: {advice}")
    order = np.random.default_rng([seed, _task_seed(task)]).permutation(len(successes))
    drawn = {successes[int(i)] for i in order[:count]}
    return TaskSplit(task, tuple(sorted(drawn)), tuple(i for i in range(len(outcomes)) if i not in drawn),
                     len(successes), sum(outcome is False for outcome in outcomes))


@dataclass(frozen=True)
class Drawn(Generic[Item]):
    """One task's drawn split of items that carry a rollout (a rollout and where it came from)."""

    split: TaskSplit
    calibration: list[Item]
    test: list[Item]


def split_by_task(items: Sequence[Item], rollout: Callable[[Item], Rollout], fraction: float = DEFAULT_FRACTION,
                  seed: int = DEFAULT_SEED) -> dict[str, Drawn[Item]]:
    """Per task (in order of first appearance), the split of ``items`` (each ``rollout(item)`` a rollout): its
    :class:`TaskSplit` (indices into the task's items, in their order in ``items``) and its calibration and test
    items."""
    by_task: dict[str, list[Item]] = {}
    for item in items:
        by_task.setdefault(rollout(item).task, []).append(item)
    result = {}
    for task, members in by_task.items():
        split = split_task(task, [rollout(m).success for m in members], fraction, seed)
        result[task] = Drawn(split, [members[i] for i in split.calibration], [members[i] for i in split.test])
    return result
