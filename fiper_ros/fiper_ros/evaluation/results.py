"""Per-rollout prediction results, the same record for the live replay and the offline oracle.

A step's ``state`` is ``"ok"``, ``"alarm"`` (latched: from the first alarm of the rollout on, as on
/fiper/alarm) or ``"unknown"``; per declared detector (the calibration's order) its decision and its windowed
score as float32 (the precision of the Score and FailureAlarm messages), so live and offline results compare
exactly (``None`` where a state is about no step: NaN on /fiper/alarm).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from fiper_ros.interface.messages import AlarmStateName
from fiper_ros.runtime.alarm import AlarmState


@dataclass(frozen=True)
class StepResult:
    """FIPER's output at one policy step: the state, and per declared detector its decision and windowed score."""

    state: AlarmStateName
    exceeded: tuple[bool, ...]
    windowed: tuple[float | None, ...]

    @classmethod
    def of_alarm(cls, msg: Any) -> StepResult:  # a FailureAlarm message (or its wire view)
        """The result a FailureAlarm message carries."""
        return cls(AlarmStateName.of_code(msg.state), tuple(bool(e) for e in msg.exceeded),
                   tuple(as_float32(v) for v in msg.eta))

    @classmethod
    def of_state(cls, state: AlarmState) -> StepResult:
        """The result of a fused state, as its FailureAlarm carries it (the windowed scores as float32)."""
        return cls(state.state, tuple(bool(e) for e in state.exceeded), tuple(as_float32(v) for v in state.windowed))


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
        alarms = [s for s, r in self.steps.items() if r.state == AlarmStateName.ALARM]
        return min(alarms) if alarms else None

    def summary(self) -> str:
        """One line: rollout, scenario, steps, first alarm step, outcome."""
        where = f" {self.task}/{self.scenario}" if self.task or self.scenario else ""
        alarm = "none" if self.first_alarm is None else f"step {self.first_alarm}"
        unknown = sum(r.state == AlarmStateName.UNKNOWN for r in self.steps.values())
        extra = f", {unknown} unknown" if unknown else ""
        return f"rollout {self.rollout_id}{where}: {len(self.steps)} steps{extra}, first alarm {alarm}, outcome {self.outcome}"

    def to_dict(self) -> dict[str, Any]:
        """JSON form (steps in order)."""
        data = asdict(self)
        data["steps"] = [{"step": s, "state": self.steps[s].state, "exceeded": list(self.steps[s].exceeded),
                          "windowed": list(self.steps[s].windowed)} for s in sorted(self.steps)]
        data["first_alarm"] = self.first_alarm
        return data


def as_float32(value: float) -> float | None:
    """``value`` rounded to float32 (as a message carries it), back as a Python float; ``None`` for NaN (a
    detector not judged), which compares equal where NaN would not."""
    return None if np.isnan(value) else float(np.float32(value))
