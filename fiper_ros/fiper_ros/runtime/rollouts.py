"""Which rollout is running and which of its policy steps were already seen."""
from __future__ import annotations

from dataclasses import dataclass, field

from fiper_ros.runtime.validation import (
    DUPLICATE_STEP,
    NEGATIVE_STEP,
    OUT_OF_ORDER_STEP,
    UNKNOWN_ROLLOUT,
    InputRejected,
)


@dataclass
class RolloutRecord:
    """What a node knows of one rollout."""

    rollout_id: int
    task: str = ""
    scenario: str = ""
    last_step: int | None = None
    steps: int = 0
    gaps: int = 0
    alarm_step: int | None = None
    outcome: str = "unknown"
    ended: bool = False
    extra: dict[str, float] = field(default_factory=dict)

    def summary(self) -> str:
        """One line for the log at the rollout's END."""
        alarm = "none" if self.alarm_step is None else str(self.alarm_step)
        where = f" {self.task}/{self.scenario}" if self.task or self.scenario else ""
        return (
            f"rollout {self.rollout_id}{where}: {self.steps} steps, {self.gaps} missing, "
            f"alarm step {alarm}, outcome {self.outcome}"
        )


class RolloutTracker:
    """The active rollout and the order of its steps.

    A START makes a rollout current and active (resetting everything of the previous one); END ends it,
    but it stays current until the next START, so a step of it that the END overtook (topics are not
    ordered) is still admitted. Steps must increase strictly within a rollout; a jump forward is accepted
    and counted as a gap. With ``auto_start`` a message of a new rollout id starts that rollout implicitly
    (for policies that publish no RolloutEvents).
    """

    def __init__(self, auto_start: bool = False) -> None:
        self.auto_start = auto_start
        self.current: RolloutRecord | None = None

    @property
    def active(self) -> RolloutRecord | None:
        """The current rollout if it has not ended."""
        return None if self.current is None or self.current.ended else self.current

    def start(self, rollout_id: int, task: str = "", scenario: str = "") -> RolloutRecord:
        """Begin ``rollout_id``; returns its fresh record."""
        self.current = RolloutRecord(rollout_id, task, scenario)
        return self.current

    def end(self, rollout_id: int, outcome: str) -> RolloutRecord | None:
        """End ``rollout_id`` if it is the active one; returns its record (or ``None``)."""
        record = self.active
        if record is None or record.rollout_id != rollout_id:
            return None
        record.outcome = outcome
        record.ended = True
        return record

    def admit(self, rollout_id: int, step: int) -> tuple[RolloutRecord, bool]:
        """Accept step ``step`` of ``rollout_id`` or raise :class:`InputRejected`.

        Returns the rollout's record and whether this message started it (``auto_start`` only).
        """
        started = False
        if step < 0:
            raise InputRejected(NEGATIVE_STEP, f"step {step} of rollout {rollout_id} is negative")
        if self.current is None or self.current.rollout_id != rollout_id:
            if not self.auto_start:
                active = "none" if self.active is None else str(self.active.rollout_id)
                raise InputRejected(UNKNOWN_ROLLOUT, f"rollout {rollout_id} is not the active rollout ({active})")
            self.start(rollout_id)
            started = True
        record = self.current
        assert record is not None
        if record.last_step is not None:
            if step == record.last_step:
                raise InputRejected(DUPLICATE_STEP, f"step {step} of rollout {rollout_id} seen twice")
            if step < record.last_step:
                raise InputRejected(
                    OUT_OF_ORDER_STEP, f"step {step} of rollout {rollout_id} after step {record.last_step}"
                )
            record.gaps += step - record.last_step - 1
        else:
            record.gaps += step
        record.last_step = step
        record.steps += 1
        return record, started
