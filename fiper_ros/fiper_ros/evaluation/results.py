"""Per-rollout prediction results, the same record for the live replay and the offline oracle.

A step's ``state`` is ``"ok"``, ``"alarm"`` (latched: from the first alarm of the rollout on, as on
/fiper/alarm) or ``"unknown"``; ``eta_*`` are the windowed scores as float32 (the precision of the
Score and FailureAlarm messages), so live and offline results compare exactly, and ``None`` for a detector
the calibration does not declare (``eta_act`` of an observation-only one: NaN on /fiper/alarm).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fiper_ros.interface.messages import ALARM, UNKNOWN



@dataclass(frozen=True)
class StepResult:
    """FIPER's output at one policy step."""

    state: str
    obs_exceeded: bool
    act_exceeded: bool
    eta_obs: float | None
    eta_act: float | None


@dataclass
class RolloutResult:
    """FIPER's output over one rollout."""

    rollout_id: int
    task: str = ""
    scenario: str = ""
    outcome: str = "unknown"
    steps: dict[int, StepResult] = field(default_factory=dict)

    @property
    def first_alarm(self) -> int | None:
        """First step whose state is ALARM."""
        alarms = [s for s, r in self.steps.items() if r.state == ALARM]
        return min(alarms) if alarms else None

    def summary(self) -> str:
        """One line: rollout, scenario, steps, first alarm step, outcome."""
        where = f" {self.task}/{self.scenario}" if self.task or self.scenario else ""
        alarm = "none" if self.first_alarm is None else f"step {self.first_alarm}"
        unknown = sum(r.state == UNKNOWN for r in self.steps.values())
        extra = f", {unknown} unknown" if unknown else ""
        return f"rollout {self.rollout_id}{where}: {len(self.steps)} steps{extra}, first alarm {alarm}, outcome {self.outcome}"

    def to_dict(self) -> dict[str, Any]:
        """JSON form (steps in order)."""
        data = asdict(self)
        data["steps"] = [{"step": s, **asdict(self.steps[s])} for s in sorted(self.steps)]
        data["first_alarm"] = self.first_alarm
        return data


def as_float32(value: float) -> float | None:
    """``value`` rounded to float32 (as a message carries it), back as a Python float; ``None`` for NaN (a
    detector not judged), which compares equal where NaN would not."""
    return None if np.isnan(value) else float(np.float32(value))
