"""What both converters share: their options, the action-channel selection and their result type."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.bags.errors import BagError
from fiper_ros.core.rollout import ACTION_SPACES, Rollout

#: ``h`` (executed actions per chunk) of the paper's tasks (Table 5), used when none is given.
EXEC_STEPS = {"sorting": 4, "stacking": 4, "pusht": 8, "push_t": 8, "pretzel": 8, "pushchair": 4, "push_chair": 4}
#: Channel selection keywords: ``all`` keeps every channel, ``auto`` is the converter's default.
ALL, AUTO = "all", "auto"

#: split name -> [(rollout, source file name)]
Converted = dict[str, list[tuple[Rollout, str]]]


def parse_channels(text: str) -> tuple[int, int] | str:
    """``"START:STOP"`` (Python slice of the action channels), ``"all"`` or ``"auto"``."""
    if text in (ALL, AUTO):
        return text
    try:
        start, stop = (int(part) for part in text.split(":"))
    except ValueError as error:
        raise BagError(f"--channels must be START:STOP, 'all' or 'auto', got {text!r}") from error
    if not 0 <= start < stop:
        raise BagError(f"--channels {text}: need 0 <= START < STOP")
    return start, stop


def select_channels(actions: np.ndarray, channels: tuple[int, int] | str, where: Path) -> np.ndarray:
    """``actions[..., START:STOP]`` of ``(T, B, H, D)`` actions (``all`` / ``auto`` resolved by the caller)."""
    if isinstance(channels, str):
        return actions
    start, stop = channels
    if stop > actions.shape[-1]:
        raise BagError(f"{where}: channels {start}:{stop} asked, the actions have D = {actions.shape[-1]}")
    return np.ascontiguousarray(actions[..., start:stop])


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
    """

    task: str = ""
    exec_steps: int = 0
    channels: tuple[int, int] | str = AUTO
    action_space: str = "ee_position"
    control_hz: float = 10.0
    max_steps: int = 0
    synthetic: bool = False

    def __post_init__(self) -> None:
        if self.action_space not in ACTION_SPACES:
            raise BagError(f"--action-space must be one of {ACTION_SPACES}, got {self.action_space!r}")
        if self.control_hz <= 0:
            raise BagError(f"--control-hz must be > 0, got {self.control_hz}")

    def exec_steps_for(self, task: str, where: Path) -> int:
        """The given ``h``, else the paper's ``h`` for ``task``."""
        if self.exec_steps:
            return self.exec_steps
        if task.lower() in EXEC_STEPS:
            return EXEC_STEPS[task.lower()]
        raise BagError(f"{where}: h of task {task!r} is not known: give --exec-steps")
