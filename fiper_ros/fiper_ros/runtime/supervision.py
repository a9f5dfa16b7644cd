"""Decision rule of the example safety supervisor: when to halt the robot.

Halt on ALARM at once; halt when the state of a rollout has been UNKNOWN, or nothing at all was heard,
for longer than the supervisor's own deadline. The UNKNOWN clock is per rollout: it restarts when the
rollout changes, and the monitor's idle state (rollout id 0, "no active rollout") never arms it, since
no robot is moving then. At most one halt per rollout (and one per silence episode).
"""
from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.runtime.alarm import ALARM, NO_ROLLOUT, UNKNOWN


@dataclass(frozen=True)
class HaltDecision:
    """Why and for which rollout the supervisor halts."""

    rollout_id: int
    reason: str


class SupervisorLogic:
    """Feed it every received alarm state and a periodic clock; it says when to halt."""

    def __init__(self, deadline_ns: int) -> None:
        self.deadline_ns = deadline_ns
        self._last_heard_ns: int | None = None
        self._unknown_since_ns: int | None = None
        self._rollout_id = NO_ROLLOUT
        self._halted: set[int] = set()
        self._silence_reported = False

    def on_state(self, rollout_id: int, state: str, reason: str, now_ns: int) -> HaltDecision | None:
        """One FailureAlarm arrived."""
        self._last_heard_ns = now_ns
        self._silence_reported = False
        if rollout_id != self._rollout_id:
            self._unknown_since_ns = None
        self._rollout_id = rollout_id
        if state == ALARM:
            self._unknown_since_ns = None
            return self._halt(f"ALARM: {reason}")
        if state == UNKNOWN and rollout_id != NO_ROLLOUT:
            if self._unknown_since_ns is None:
                self._unknown_since_ns = now_ns
            return self.on_clock(now_ns)
        self._unknown_since_ns = None
        return None

    def on_clock(self, now_ns: int) -> HaltDecision | None:
        """Periodic check for silence and lasting UNKNOWN."""
        if self._last_heard_ns is None:
            return None  # never heard the monitor: nothing is running yet
        if now_ns - self._last_heard_ns > self.deadline_ns and not self._silence_reported:
            self._silence_reported = True
            return HaltDecision(self._rollout_id, f"no alarm message for {(now_ns - self._last_heard_ns) / 1e9:.2f} s")
        if self._unknown_since_ns is not None and now_ns - self._unknown_since_ns > self.deadline_ns:
            return self._halt(f"UNKNOWN for {(now_ns - self._unknown_since_ns) / 1e9:.2f} s")
        return None

    def _halt(self, reason: str) -> HaltDecision | None:
        if self._rollout_id in self._halted:
            return None
        self._halted.add(self._rollout_id)
        return HaltDecision(self._rollout_id, reason)
