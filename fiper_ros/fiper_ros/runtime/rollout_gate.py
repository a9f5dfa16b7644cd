"""A node's rollouts: START and END, the START gate for inputs that overtook their START, and the step order.

The one home of the rule every node applies to a stream of per-step inputs (the scoring nodes to embeddings,
action batches and signals, the fusion node to scores): a START makes a rollout current and active (a repeated
START of the running rollout changes nothing: its steps, windows and latch are kept); END ends it, but it stays
current, so a step of it that the END overtook is still taken. An input of another rollout waits for that
rollout's START in the gate (bounded in count, size and age), unless that rollout ended recently (a late input:
refused) or the node starts rollouts from their first input (``auto_start``). :meth:`RolloutGate.admit` then
checks the step order (:class:`~fiper_ros.runtime.rollout_tracker.RolloutTracker`).
"""
from __future__ import annotations

from enum import Enum
from typing import Generic, TypeVar

from fiper_ros.runtime.pending import StartGate
from fiper_ros.runtime.rollout_tracker import RolloutRecord, RolloutTracker
from fiper_ros.runtime.validation import DEFAULT_MAX_PENDING_ELEMENTS, DEFAULT_MAX_STEP_GAP

Item = TypeVar("Item")


class Route(Enum):
    """What becomes of an arriving input."""

    NOW = "now"
    """Of the current rollout (or one ``auto_start`` starts): process it."""
    WAIT = "wait"
    """Of a rollout whose START has not arrived: it waits in the gate."""
    LATE = "late"
    """Of a rollout that ended recently, not the current one: refuse it."""


class RolloutGate(Generic[Item]):
    """The rollouts of one node and the inputs that wait for their START (module docstring)."""

    def __init__(self, auto_start: bool = False, max_step_gap: int = DEFAULT_MAX_STEP_GAP,
                 start_wait_ns: int = 1_000_000_000, max_waiting: int = 64,
                 max_waiting_size: int | None = DEFAULT_MAX_PENDING_ELEMENTS) -> None:
        self.tracker = RolloutTracker(auto_start, max_step_gap)
        self.waiting: StartGate[Item] = StartGate(start_wait_ns, max_waiting, max_waiting_size)
        #: STARTs of the rollout already active (ignored: its steps, windows and latch are kept).
        self.repeated_starts = 0

    @property
    def auto_start(self) -> bool:
        """Whether an input of a new rollout id starts that rollout (no RolloutEvents needed)."""
        return self.tracker.auto_start

    @property
    def current(self) -> RolloutRecord | None:
        """The rollout of the latest START (also after its END: its late steps are still taken)."""
        return self.tracker.current

    @property
    def active(self) -> RolloutRecord | None:
        """The current rollout if it has not ended."""
        return self.tracker.active

    def start(self, rollout_id: int, task: str = "", scenario: str = "", max_steps: int = 0) -> list[Item] | None:
        """A START: ``None`` if it repeats the running rollout's (counted, nothing changes), else the inputs of
        the rollout that waited for it, in arrival order, to be processed now."""
        active = self.tracker.active
        if active is not None and active.rollout_id == rollout_id:
            self.repeated_starts += 1
            return None
        self.tracker.start(rollout_id, task, scenario, max_steps)
        return self.waiting.start(rollout_id)

    def end(self, rollout_id: int, outcome: str) -> RolloutRecord | None:
        """An END: the rollout's record if it was the active one (its late inputs are known as such from now on)."""
        self.waiting.end(rollout_id)
        return self.tracker.end(rollout_id, outcome)

    def route(self, rollout_id: int) -> Route:
        """What becomes of an input of ``rollout_id`` (:class:`Route`)."""
        current = self.tracker.current
        if (current is not None and current.rollout_id == rollout_id) or self.tracker.auto_start:
            return Route.NOW
        return Route.LATE if self.waiting.has_ended(rollout_id) else Route.WAIT

    def wait(self, rollout_id: int, item: Item, now_ns: int, size: int = 1) -> list[Item]:
        """Keep ``item`` until its rollout's START; returns the oldest inputs pushed out of the full gate."""
        return self.waiting.add(rollout_id, item, now_ns, size)

    def expire(self, now_ns: int) -> list[Item]:
        """The inputs that waited longer than the START wait, removed."""
        return self.waiting.expire(now_ns)

    def admit(self, rollout_id: int, step: int) -> tuple[RolloutRecord, bool]:
        """Accept step ``step`` of ``rollout_id`` or raise :class:`~fiper_ros.runtime.validation.InputRejected`
        (:meth:`RolloutTracker.admit`); returns the rollout's record and whether this input started it."""
        return self.tracker.admit(rollout_id, step)
