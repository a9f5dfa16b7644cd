"""A fitted calibration: per task, every declared detector's scorer and threshold, and what it promises."""

from __future__ import annotations

import hashlib
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from fiper_ros.core.calibration.settings import CalibrationSettings
from fiper_ros.core.calibration_file import CALIBRATION_FILE, FORMAT_VERSION, CalibrationError, merged_split
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import info
from fiper_ros.core.profiles import Profile
from fiper_ros.core.scorers import Scorer
from fiper_ros.core.thresholds import GUARANTEED_KINDS, Threshold


#: Where the model files of a calibration of several tasks lie: ``tasks/<task>/``.
TASKS_DIRECTORY = "tasks"
_TASK_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")


def task_directory(directory: Path, calibration_tasks: tuple[str, ...], task: str) -> Path:
    """Where ``task``'s model files lie: the calibration directory itself for one task, else ``tasks/<task>/``."""
    if len(calibration_tasks) == 1:
        return directory
    if not _TASK_NAME.match(task):
        raise CalibrationError(f"task name {task!r} cannot name a folder of model files (letters, digits, _ . -)")
    return directory / TASKS_DIRECTORY / task


class CalibrationMismatch(CalibrationError):
    """Live data does not match the calibration (e.g. another policy, robot or task)."""

    def __init__(self, field_name: str, expected: Any, got: Any) -> None:  # any compared value
        super().__init__(f"calibration mismatch for {field_name}: expected {expected}, got {got}")
        self.field = field_name
        self.expected = expected
        self.got = got


@dataclass(frozen=True)
class Layout:
    """What the calibrated policy publishes: the embedding size and, when a declared detector reads the action
    batches, their chunk shape, ``h`` and action space (else 0 and "": any batches, or none, fit)."""

    embedding_dim: int
    action_dim: int = 0
    horizon: int = 0
    exec_steps: int = 0
    action_space: str = ""

    @property
    def has_actions(self) -> bool:
        """Whether the layout fixes the action batches."""
        return self.horizon > 0

    def to_dict(self) -> dict[str, Any]:
        """Plain data (the action fields only when fixed)."""
        if not self.has_actions:
            return {"embedding_dim": self.embedding_dim}
        return {"embedding_dim": self.embedding_dim, "action_dim": self.action_dim, "horizon": self.horizon,
                "exec_steps": self.exec_steps, "action_space": self.action_space}


@dataclass
class DetectorPart:
    """One detector of one task: its fitted scorer and its threshold ``gamma_d(t)``."""

    scorer: Scorer
    threshold: Threshold


@dataclass
class TaskPart:
    """Everything a calibration fitted for one task."""

    detectors: dict[str, DetectorPart]
    num_rollouts: int
    split: dict[str, Any] = field(default_factory=dict)
    """Which successes fitted what (by rollout id), how many rollouts each threshold rests on (empty for a
    calibration written before it was recorded)."""


@dataclass
class Calibration:
    """A fitted calibration: the settings, the policy's layout and, per task (``""``: rollouts that named none),
    every declared detector's scorer and threshold; ``joint`` summarises a joint combine's conformal factor (the
    votes; pooled over tasks also ``k`` and the conformal rollouts behind it); ``false_alarms`` is the
    leave-one-out estimate of the false-alarm rate on new successes; ``auto`` how ``--auto`` chose the configuration."""

    settings: CalibrationSettings
    layout: Layout
    tasks: dict[str, TaskPart]
    joint: dict[str, Any] = field(default_factory=dict)
    false_alarms: dict[str, Any] = field(default_factory=dict)
    auto: dict[str, Any] = field(default_factory=dict)
    """How ``--auto`` chose the configuration (:meth:`fiper_ros.core.auto.AutoChoice.record`); empty: chosen by
    hand."""

    @property
    def guarantee(self) -> str:
        """What the calibration promises about false alarms on new successful rollouts (:func:`guarantee`)."""
        return guarantee(self.settings)

    def content(self) -> dict[str, Any]:
        """The content of ``calibration.yaml`` (format 3) without its hash."""
        return {
            "format_version": FORMAT_VERSION,
            "settings": self.settings.to_dict(),
            "layout": self.layout.to_dict(),
            "guarantee": self.guarantee,
            **({"joint": dict(self.joint)} if self.joint else {}),
            "tasks": {name: {"num_rollouts": part.num_rollouts,
                             **({"split": part.split} if part.split else {}),
                             "detectors": {d: {**p.scorer.entry(), "threshold": p.threshold.to_dict()}
                                           for d, p in part.detectors.items()}}
                      for name, part in self.tasks.items()},
            **({"false_alarm_estimate": self.false_alarms} if self.false_alarms else {}),
            **({"auto": self.auto} if self.auto else {}),
        }

    def hash_of(self, content: dict[str, Any]) -> str:
        """SHA-256 over YAML ``content`` (without the hash) and every model's digest (tasks and detectors in order)."""
        digest = hashlib.sha256(yaml.safe_dump(content, sort_keys=True).encode())
        for part in self.tasks.values():
            for detector in part.detectors.values():
                digest.update(detector.scorer.digest().encode())
        return digest.hexdigest()

    @property
    def content_hash(self) -> str:
        """SHA-256 over the YAML content (without the hash) and every model's digest."""
        return self.hash_of(self.content())

    def save(self, directory: str | Path) -> Path:
        """Write ``calibration.yaml`` and the models' files into ``directory`` (a calibration of several tasks: each
        task's in ``tasks/<task>/``); returns the YAML path."""
        directory = Path(directory)
        names = tuple(self.tasks)
        for name, part in self.tasks.items():
            where = task_directory(directory, names, name)
            where.mkdir(parents=True, exist_ok=True)
            for detector in part.detectors.values():
                detector.scorer.save(where)
        data = self.content()
        data["content_hash"] = self.hash_of(data)
        path = directory / CALIBRATION_FILE
        path.write_text(yaml.safe_dump(data, sort_keys=False))
        return path

    @property
    def profile(self) -> Profile:
        """The method profile."""
        return self.settings.profile_obj

    @property
    def detectors(self) -> tuple[str, ...]:
        """The declared detectors, in the fusion's order."""
        return self.settings.detectors

    @property
    def num_rollouts(self) -> int:
        """Successful calibration rollouts over every task."""
        return sum(part.num_rollouts for part in self.tasks.values())

    @property
    def split(self) -> dict[str, Any]:
        """Which successes fitted what over every task (:func:`~fiper_ros.core.calibration_file.merged_split`; empty
        for a calibration written before it was recorded): what tells the calibration's own rollouts from new ones."""
        return merged_split([part.split for part in self.tasks.values()])

    @property
    def named_tasks(self) -> tuple[str, ...]:
        """The tasks of the calibration rollouts that named one (empty: they named none)."""
        return tuple(t for t in self.tasks if t)

    def part(self, task: str = "") -> TaskPart:
        """The part of ``task``: its own, or the only one when either side names no task (a calibration of rollouts
        without a task serves every task, and a rollout without a task is judged by a one-task calibration);
        :class:`CalibrationMismatch` for a task the calibration never saw."""
        if task in self.tasks:
            return self.tasks[task]
        if len(self.tasks) == 1 and (not task or "" in self.tasks):
            return next(iter(self.tasks.values()))
        raise CalibrationMismatch("task", " or ".join(self.named_tasks) or "(none)", task or "(none)")

    def threshold(self, detector: str, task: str = "") -> Threshold:
        """``gamma_d(t)`` of a declared detector for ``task``."""
        return self._detector(detector, task).threshold

    def scorer(self, detector: str, task: str = "") -> Scorer:
        """The fitted scorer of a declared detector for ``task``."""
        return self._detector(detector, task).scorer

    def _detector(self, detector: str, task: str) -> DetectorPart:
        if detector not in self.detectors:
            raise CalibrationError(f"detector {detector!r} is not calibrated here (detectors "
                                   f"{','.join(self.detectors)})")
        return self.part(task).detectors[detector]

    def check_compatible(self, embedding_dim: int | None = None, action_dim: int | None = None,
                         horizon: int | None = None, *, exec_steps: int | None = None,
                         action_space: str | None = None, task: str | None = None) -> None:
        """:class:`CalibrationMismatch` naming the first field that differs (``None``: not checked; the action
        layout only when the calibration fixes it; a task when the calibration cannot judge it: :meth:`part`)."""
        layout = self.layout
        checked = (("embedding_dim", embedding_dim), ("action_dim", action_dim), ("horizon", horizon),
                   ("exec_steps", exec_steps))
        for name, got in checked if layout.has_actions else checked[:1]:
            expected = getattr(layout, name)
            if got is not None and int(got) != expected:
                raise CalibrationMismatch(name, expected, int(got))
        if layout.has_actions and action_space is not None and action_space != layout.action_space:
            raise CalibrationMismatch("action_space", layout.action_space, action_space)
        if task is not None:
            self.part(task)


def promised_rate(settings: CalibrationSettings) -> float:
    """The bound on the false-alarm rate over new successful rollouts that Prop. 1 gives these settings (if their
    split and threshold kind are covered at all, see :func:`guarantee`): ``delta`` with AND (an alarm needs every
    detector's threshold exceeded), with a joint combine (one conformal factor) and with one detector alone;
    ``N delta`` with an OR of N thresholds at ``delta`` each (the union bound)."""
    return settings.delta * settings.combine_rule.promised_multiple(len(settings.detectors))


def guarantee(settings: CalibrationSettings) -> str:
    """What the calibration promises about false alarms on new successful rollouts, in one sentence."""
    if settings.threshold not in GUARANTEED_KINDS:
        return (f"none: a {settings.threshold} threshold bounds each step, not a whole rollout "
                "(docs/method.md, 'What each threshold guarantees')")
    rate = promised_rate(settings)
    count = len(settings.detectors)
    how = ""
    if settings.combine_rule.mode is CombineMode.OR and count > 1:
        how = (f"; OR of {count} thresholds at delta {settings.delta:g} each: the union bound, calibrate at --delta "
               f"{settings.delta / count:g} for {settings.delta:g}, or combine max for one shared threshold")
    elif settings.combine_rule.joint and count > 1:
        how = f"; {settings.combine_rule} of {count} detectors under one conformal threshold"
    if settings.pooled:
        how += "; pooled over the tasks: over all tasks' successes in their calibration proportions, not per task"
    if settings.split == "split":
        return (f"at most {rate:g} of new successful rollouts alarmed (Proposition 1: split conformal, "
                f"models and thresholds on disjoint successes{how})")
    if settings.split == "cross":
        return (f"about {rate:g} (cross-fitted: approximate, the deployed model saw every calibration "
                f"rollout; no finite-sample guarantee{how})")
    if all(not info(d).fitted for d in settings.detectors):
        return f"at most {rate:g} of new successful rollouts alarmed (nothing fitted on the successes{how})"
    return "not covered by Proposition 1 (models and thresholds on the same successes, --same-data)"
