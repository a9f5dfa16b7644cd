"""Decision rule of the example safety supervisor: when to halt the robot.

Halt on ALARM at once; halt when the state of a rollout has been UNKNOWN for longer than the supervisor's
own deadline; halt when nothing at all was heard for longer than the silence deadline. The UNKNOWN clock
is per rollout: it restarts when the rollout changes, and the monitor's idle state (rollout id 0, "no
active rollout") never arms it, since no robot is moving then. While a rollout runs (between its START
and END events) the silence deadline follows the measured period of the monitor's per-step decisions
(``silence_periods`` of them, at least ``silence_floor_ns``; the period measured from the decisions' own
stamps, the policy steps'): a fusion node that died or hangs is noticed
within a few policy periods; otherwise it is the deadline. Under simulated time silence must also have
lasted ``silence_floor_ns`` of wall-clock (steady) time: a supervisor starved of CPU can take a burst of
``/clock`` before the alarm messages queued beside it, and sim time then jumps past a deadline that no
silence caused. At most one halt per rollout (and one per silence episode). While the alarm stream cannot
be attributed to the suite (:meth:`SupervisorLogic.suspect`: a second or unexpected publisher of the alarm
topic), an OK counts as UNKNOWN, from the moment the doubt arises: the supervisor halts when it lasts longer
than the deadline. An ALARM halts at once, whoever said it.
"""
from __future__ import annotations

from collections import deque
from dataclasses import dataclass

from fiper_ros.interface.messages import NO_ROLLOUT, AlarmStateName
from fiper_ros.runtime.stats import PeriodEstimator

#: How many recent halts the supervisor remembers (to halt each rollout once): bounded, whatever the rollout ids.
HALTED_MEMORY = 64


@dataclass(frozen=True)
class HaltDecision:
    """Why and for which rollout the supervisor halts."""

    rollout_id: int
    reason: str


class SupervisorLogic:
    """Feed it every received alarm state, the rollout events and a periodic clock; it says when to halt."""

    def __init__(self, deadline_ns: int, silence_periods: float = 0.0, silence_floor_ns: int = 0) -> None:
        if deadline_ns <= 0 or silence_periods < 0 or silence_floor_ns < 0:
            raise ValueError("deadline_ns must be > 0, silence_periods and silence_floor_ns >= 0")
        self.deadline_ns = deadline_ns
        self.silence_periods = silence_periods
        self.silence_floor_ns = silence_floor_ns
        self.period = PeriodEstimator()
        self._running: int | None = None
        self._last_heard_ns: int | None = None
        self._last_heard_steady_ns: int | None = None
        self._unknown_since_ns: int | None = None
        self._rollout_id = NO_ROLLOUT
        self._halted: deque[int] = deque(maxlen=HALTED_MEMORY)  # the recent rollouts halted
        self._silence_reported = False
        self._unknown_reason = ""
        self.suspicion = ""
        """Why the alarm stream cannot be attributed to the suite now (``""``: it can)."""

    def on_event(self, rollout_id: int, started: bool) -> None:
        """A RolloutEvent: ``started`` for its START, False for its END."""
        if started:
            if rollout_id != self._running:
                self.period.reset()
            self._running = rollout_id
        elif rollout_id == self._running:
            self._running = None

    def silence_deadline(self) -> int:
        """How long silence is tolerated now (see the module docstring)."""
        if self._running is None:
            return self.deadline_ns
        return self.period.deadline_ns(self.silence_periods, self.silence_floor_ns, self.deadline_ns)

    def on_state(self, rollout_id: int, state: AlarmStateName, reason: str, now_ns: int, step: int = 0,
                 heartbeat: bool = True, steady_ns: int | None = None, stamp_ns: int | None = None
                 ) -> HaltDecision | None:
        """One FailureAlarm arrived (``heartbeat`` False: a new step's decision, whose ``stamp_ns`` (its
        header stamp: the policy step's) measures the policy period; ``steady_ns``: the wall-clock time, when
        ``now_ns`` is simulated). The period is the stamps', not the arrivals': decisions taken in one burst
        (a starved supervisor) would measure a period near 0 and turn one ordinary step of silence into a halt."""
        if not heartbeat and stamp_ns is None:
            raise ValueError("a step's decision needs its stamp (the FailureAlarm's header stamp)")
        self._last_heard_ns = now_ns
        self._last_heard_steady_ns = steady_ns
        self._silence_reported = False
        if not heartbeat and rollout_id == self._running:
            self.period.add(step, stamp_ns)
        if rollout_id != self._rollout_id:
            self._unknown_since_ns = None
        self._rollout_id = rollout_id
        if state == AlarmStateName.ALARM:
            self._unknown_since_ns = None
            return self._halt(f"ALARM: {reason}")
        if self.suspicion:
            state, reason = AlarmStateName.UNKNOWN, self._doubt()
        if state == AlarmStateName.UNKNOWN and rollout_id != NO_ROLLOUT:
            if self._unknown_since_ns is None:
                self._unknown_since_ns = now_ns
            self._unknown_reason = reason
            return self.on_clock(now_ns, steady_ns)
        self._unknown_since_ns = None
        return None

    def suspect(self, reason: str, now_ns: int, steady_ns: int | None = None) -> HaltDecision | None:
        """Say why the alarm stream cannot be attributed to the suite now (``""``: it can again). The
        UNKNOWN clock of a rollout runs from now; the next OK without doubt stops it (``steady_ns``: see
        :meth:`on_state`)."""
        self.suspicion = reason
        if reason and self._rollout_id != NO_ROLLOUT and self._unknown_since_ns is None:
            self._unknown_since_ns = now_ns
            self._unknown_reason = self._doubt()
        return self.on_clock(now_ns, steady_ns)

    def _doubt(self) -> str:
        return f"the alarm stream cannot be attributed to the suite: {self.suspicion}"

    def on_clock(self, now_ns: int, steady_ns: int | None = None) -> HaltDecision | None:
        """Periodic check for silence and lasting UNKNOWN (``steady_ns``: see :meth:`on_state`)."""
        if self._last_heard_ns is None:
            return None  # never heard the monitor: nothing is running yet
        quiet_in_wall_time = (steady_ns is None or self._last_heard_steady_ns is None
                              or steady_ns - self._last_heard_steady_ns > self.silence_floor_ns)
        if now_ns - self._last_heard_ns > self.silence_deadline() and quiet_in_wall_time \
                and not self._silence_reported:
            self._silence_reported = True
            return HaltDecision(self._rollout_id, f"no alarm message for {(now_ns - self._last_heard_ns) / 1e9:.2f} s")
        if self._unknown_since_ns is not None and now_ns - self._unknown_since_ns > self.deadline_ns:
            return self._halt(f"UNKNOWN for {(now_ns - self._unknown_since_ns) / 1e9:.2f} s ({self._unknown_reason})")
        return None

    def _halt(self, reason: str) -> HaltDecision | None:
        if self._rollout_id in self._halted:
            return None
        self._halted.append(self._rollout_id)
        return HaltDecision(self._rollout_id, reason)
