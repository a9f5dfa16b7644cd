"""Which rollout is running and which of its policy steps were already seen."""
from __future__ import annotations

from dataclasses import dataclass, field

from fiper_ros.runtime.validation import (
    BEYOND_MAX_STEPS,
    DEFAULT_MAX_STEP_GAP,
    DUPLICATE_STEP,
    NEGATIVE_STEP,
    OUT_OF_ORDER_STEP,
    STEP_GAP,
    UNKNOWN_ROLLOUT,
    InputRejected,
)


@dataclass
class RolloutRecord:
    """What a node knows of one rollout."""

    rollout_id: int
    task: str = ""
    scenario: str = ""
    max_steps: int = 0
    """The rollout's limit of policy steps from its START (0: not known)."""
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
    and counted as a gap, up to ``max_step_gap`` steps, and a step must lie below the START's ``max_steps``
    (when given): a message field never sizes the work that follows it. With ``auto_start`` a message of a
    new rollout id starts that rollout implicitly (for policies that publish no RolloutEvents).
    """

    def __init__(self, auto_start: bool = False, max_step_gap: int = DEFAULT_MAX_STEP_GAP) -> None:
        if max_step_gap < 0:
            raise ValueError(f"max_step_gap must be >= 0, got {max_step_gap}")
        self.auto_start = auto_start
        self.max_step_gap = max_step_gap
        self.current: RolloutRecord | None = None

    @property
    def active(self) -> RolloutRecord | None:
        """The current rollout if it has not ended."""
        return None if self.current is None or self.current.ended else self.current

    def start(self, rollout_id: int, task: str = "", scenario: str = "", max_steps: int = 0) -> RolloutRecord:
        """Begin ``rollout_id``; returns its fresh record."""
        self.current = RolloutRecord(rollout_id, task, scenario, max_steps)
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

        Returns the rollout's record and whether this message started it (``auto_start`` only). A rejected
        step changes nothing: the next valid step is judged as if the rejected one never came.
        """
        if step < 0:
            raise InputRejected(NEGATIVE_STEP, f"step {step} of rollout {rollout_id} is negative")
        record = self.current
        new = record is None or record.rollout_id != rollout_id
        if new and not self.auto_start:
            active = "none" if self.active is None else str(self.active.rollout_id)
            raise InputRejected(UNKNOWN_ROLLOUT, f"rollout {rollout_id} is not the active rollout ({active})")
        last = -1 if new or record.last_step is None else record.last_step
        if step == last:
            raise InputRejected(DUPLICATE_STEP, f"step {step} of rollout {rollout_id} seen twice")
        if step < last:
            raise InputRejected(OUT_OF_ORDER_STEP, f"step {step} of rollout {rollout_id} after step {last}")
        if step - last - 1 > self.max_step_gap:
            raise InputRejected(STEP_GAP, f"step {step} of rollout {rollout_id} after step {last}: a gap of "
                                          f"{step - last - 1} steps, more than max_step_gap={self.max_step_gap}")
        if not new and record.max_steps and step >= record.max_steps:
            raise InputRejected(BEYOND_MAX_STEPS, f"step {step} of rollout {rollout_id}: the rollout has at most "
                                                  f"{record.max_steps} steps (its START)")
        if new:
            record = self.start(rollout_id)
        record.gaps += step - last - 1
        record.last_step = step
        record.steps += 1
        return record, new
