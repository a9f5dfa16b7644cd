"""What the converters share: their options, the bound on what they read, the action-channel selection and
their result type (the channel option itself is parsed by :func:`fiper_ros.commands.options.parse_channels`)."""
from __future__ import annotations

from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from fiper_ros.bagio.errors import BagError
from fiper_ros.core.data_split import DEFAULT_FRACTION, DEFAULT_SEED, DataSplitError, check_draw
from fiper_ros.core.rollout import ACTION_SPACES, Rollout, RolloutError, check_signal_name

#: ``h`` (executed actions per chunk) of the paper's tasks (Table 5), used when none is given.
EXEC_STEPS = {"sorting": 4, "stacking": 4, "pusht": 8, "push_t": 8, "pretzel": 8, "pushchair": 4, "push_chair": 4}
#: Channel selection keywords: ``all`` keeps every channel, ``auto`` is the converter's default.
ALL, AUTO = "all", "auto"

#: Default of ``--max-mb``: the most a conversion reads (source files and the arrays it converts), MB.
DEFAULT_MAX_MB = 4096.0
MB = 1_000_000

#: split name (or ``NO_SPLIT``: the source gives none, :mod:`fiper_ros.core.data_split`) -> [(rollout, source file name)]
Converted = dict[str, list[tuple[Rollout, str]]]


def select_channels(actions: np.ndarray, channels: tuple[int, int] | str, where: Path) -> np.ndarray:
    """``actions[..., START:STOP]`` of ``(T, B, H, D)`` actions (``all`` / ``auto`` resolved by the caller)."""
    if isinstance(channels, str):
        return actions
    start, stop = channels
    if stop > actions.shape[-1]:
        raise BagError(f"{where}: channels {start}:{stop} asked, the actions have D = {actions.shape[-1]}")
    return np.ascontiguousarray(actions[..., start:stop])


@dataclass(frozen=True)
class Keys:
    """Names of the fields of the ``generic`` format (docs/bags.md, "Converters"), one option each."""

    embeddings: str = "embeddings"
    actions: str = "actions"
    success: str = "success"
    rollout: str = "rollout_id"
    step: str = "step"
    split: str = "split"
    task: str = "task"
    scenario: str = "scenario"
    signals: str = ""
    """The per-step signals ``[T, K]`` (or ``[T]``, one signal); empty: none are read."""

    def __post_init__(self) -> None:
        names = [getattr(self, item.name) for item in fields(self) if item.name != "signals" or self.signals]
        if not all(names) or len(set(names)) != len(names):
            raise BagError(f"the --*-key options must name distinct, non-empty keys, got {', '.join(map(repr, names))}")


class Budget:
    """What one conversion may read: every source file and the arrays converted so far together stay within
    ``--max-mb`` (all rollouts are held in memory until the bags are written)."""

    def __init__(self, max_mb: float) -> None:
        self.limit = int(max_mb * MB)
        self.used = 0

    def check_file(self, path: Path, size: int, what: str = "") -> None:
        """Refuse ``path`` before it is read if its ``size`` bytes (on disk, or ``what`` it declares) do not
        fit beside the arrays converted so far."""
        if self.used + size > self.limit:
            raise BagError(f"{path}: {size / MB:.1f} MB{what or ' on disk'}, with {self.used / MB:.1f} MB converted "
                           f"before, exceeds --max-mb {self.limit / MB:g}")

    def take(self, where: str, rollout: Rollout) -> None:
        """Count the arrays of a converted rollout (``where``: its name in messages) against the bound."""
        self.used += rollout.embeddings.nbytes + (0 if rollout.actions is None else rollout.actions.nbytes) + sum(
            values.nbytes for values in rollout.signals.values())
        if self.used > self.limit:
            raise BagError(f"{where}: the converted arrays reach {self.used / MB:.1f} MB, more than --max-mb "
                           f"{self.limit / MB:g}")


@dataclass(frozen=True)
class ConvertOptions:
    """Options of ``fiper convert``.

    Attributes:
        task: Task name (default: from the source directory).
        exec_steps: ``h``; default from the data (Sentinel) or the paper's value for the task.
        channels: Action channels kept, ``(start, stop)``, ``"all"`` or ``"auto"``.
        action_space: Action space of the (kept) channels.
        control_hz: Environment steps per second (sets the bag's time line).
        max_steps: Maximum policy steps of a rollout, written in the RolloutEvents (0 = unknown).
        synthetic: Mark the bags as synthetic data.
        max_mb: The most one conversion reads, MB (:class:`Budget`).
        keys: Field names of the ``generic`` format.
        signal_names: Names of the columns of ``keys.signals`` (one per column; default for a ``[T]`` key: the key).
        calibration_fraction: Of data without a split, the fraction of each task's successes drawn into its
            calibration set (:mod:`fiper_ros.core.data_split`).
        split_seed: Seed of that draw.
    """

    task: str = ""
    exec_steps: int = 0
    channels: tuple[int, int] | str = AUTO
    action_space: str = "ee_position"
    control_hz: float = 10.0
    max_steps: int = 0
    synthetic: bool = False
    max_mb: float = DEFAULT_MAX_MB
    keys: Keys = field(default_factory=Keys)
    signal_names: tuple[str, ...] = ()
    calibration_fraction: float = DEFAULT_FRACTION
    split_seed: int = DEFAULT_SEED

    def __post_init__(self) -> None:
        if self.action_space not in ACTION_SPACES:
            raise BagError(f"--action-space must be one of {ACTION_SPACES}, got {self.action_space!r}")
        if self.control_hz <= 0:
            raise BagError(f"--control-hz must be > 0, got {self.control_hz}")
        if not self.max_mb > 0:
            raise BagError(f"--max-mb must be > 0, got {self.max_mb}")
        if self.signal_names and not self.keys.signals:
            raise BagError("--signal-names names the columns of --signals-key: give --signals-key too")
        for name in self.signal_names:
            try:
                check_signal_name(name, "--signal-names")
            except RolloutError as error:
                raise BagError(str(error)) from error
        if len(set(self.signal_names)) != len(self.signal_names):
            raise BagError(f"--signal-names repeats a name ({', '.join(self.signal_names)})")
        try:
            check_draw(self.calibration_fraction, self.split_seed, ("--calibration-fraction", "--split-seed"))
        except DataSplitError as error:
            raise BagError(str(error)) from error

    def exec_steps_for(self, task: str, where: Path) -> int:
        """The given ``h``, else the paper's ``h`` for ``task``."""
        if self.exec_steps:
            return self.exec_steps
        if task.lower() in EXEC_STEPS:
            return EXEC_STEPS[task.lower()]
        raise BagError(f"{where}: h of task {task!r} is not known: give --exec-steps")
