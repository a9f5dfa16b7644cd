"""What the driver saw of one rollout: the declared detectors' windowed scores against their thresholds, the alarm,
the outcome.

Pure bookkeeping (no rclpy): the driver (:mod:`fiper_ros.client.driver`) feeds it the values of the Score,
FailureAlarm, ActionChunkBatch and RolloutEvent messages of one rollout; the demo's figure and summary
and ``fiper collect --ros`` read it back. A trace keeps the scores of the detectors its calibration declares
(FIPER's pair, or RND-OE alone for an observation-only one: :mod:`fiper_ros.core.detectors`) and no others.
"""
from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fiper_ros.core.detectors import DETECTORS, judged_by

#: Messages of rollouts without a trace kept for it (the oldest go first): a rollout's first scores,
#: batches and alarms can arrive before the reset's answer that names it.
EARLY_MESSAGES = 256


@dataclass
class ScoreSeries:
    """One detector's stream over a rollout, by policy step."""

    windowed: dict[int, float] = field(default_factory=dict)
    """Windowed score ``eta`` (eq. 2 for RND-OE, eq. 5 for ACE) per step."""
    threshold: dict[int, float] = field(default_factory=dict)
    """Threshold ``gamma`` in force at each step."""
    exceeded: dict[int, bool] = field(default_factory=dict)

    def add(self, step: int, windowed: float, threshold: float, exceeded: bool) -> None:
        """Record the score of ``step`` (a repeated step replaces the earlier value)."""
        self.windowed[step] = float(windowed)
        self.threshold[step] = float(threshold)
        self.exceeded[step] = bool(exceeded)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(steps, windowed, threshold)`` sorted by step."""
        steps = np.array(sorted(self.windowed), dtype=int)
        return (steps, np.array([self.windowed[s] for s in steps], dtype=float),
                np.array([self.threshold[s] for s in steps], dtype=float))


@dataclass
class RolloutTrace:
    """The driver's record of one rollout.

    Attributes:
        label: What the rollout is meant to show, e.g. ``"in-distribution"``.
        scenario: Sim scenario name.
        seed: Episode seed.
        rollout_id: The bridge's id, once the reset answered.
        detectors: The detectors the calibration declares, which judge the rollout.
        scores: Per declared detector.
        combine: How the fusion node combined them, as its alarms say (``FailureAlarm.combine``; ``""`` before
            the first alarm, and for one detector alone).
        alarm_step: First policy step whose FailureAlarm state was ALARM.
        alarm_text: That alarm as printed (the declared scores against their thresholds).
        unknown_steps: Steps reported UNKNOWN.
        outcome: ``"success"``, ``"failure"`` or ``""`` while running.
        steps_started: Policy steps for which an action-chunk batch was seen.
        max_steps: The bridge's limit of policy steps for the rollout.
        started_ns: Stamp of the START event (the bridge's clock).
        ended_ns: Stamp of the END event.
    """

    label: str
    scenario: str
    seed: int
    rollout_id: int = 0
    detectors: tuple[str, ...] = DETECTORS
    scores: dict[str, ScoreSeries] = field(init=False)
    combine: str = ""
    alarm_step: int | None = None
    alarm_text: str = ""
    unknown_steps: set[int] = field(default_factory=set)
    outcome: str = ""
    steps_started: int = 0
    max_steps: int = 0
    started_ns: int = 0
    ended_ns: int = 0

    def __post_init__(self) -> None:
        self.scores = {name: ScoreSeries() for name in self.detectors}

    @property
    def ended(self) -> bool:
        """Whether the rollout's END event was seen."""
        return bool(self.outcome)

    def scored_steps(self) -> int:
        """Steps with the scores of every declared detector (none declared: 0)."""
        steps = [set(series.windowed) for series in self.scores.values()]
        return len(set.intersection(*steps)) if steps else 0

    def verdict(self) -> str:
        """One phrase: what FIPER did on this rollout given its outcome."""
        if self.alarm_step is None:
            return "no alarm, task succeeded" if self.outcome == "success" else "no alarm: a missed failure"
        if self.outcome == "success":
            return f"alarm at step {self.alarm_step}, yet the task succeeded: a false alarm"
        return f"alarm at step {self.alarm_step}: the supervisor halted the robot"

    def to_dict(self) -> dict[str, Any]:
        """JSON form for the run's summary file: a series per declared detector, under its name."""
        def series(name: str) -> dict[str, list[float]]:
            steps, windowed, threshold = self.scores[name].arrays()
            return {"steps": steps.tolist(), "windowed": windowed.tolist(), "threshold": threshold.tolist()}

        return {"label": self.label, "scenario": self.scenario, "seed": self.seed, "rollout_id": self.rollout_id,
                "outcome": self.outcome, "alarm_step": self.alarm_step, "alarm": self.alarm_text,
                "policy_steps": self.steps_started, "scored_steps": self.scored_steps(),
                "unknown_steps": sorted(self.unknown_steps), "verdict": self.verdict(),
                "detectors": list(self.detectors), "combine": self.combine,
                "judged_by": judged_by(self.detectors, self.combine),
                **{name: series(name) for name in self.detectors}}


class RolloutEvents:
    """The START / END stamps of rollouts, paired with their traces whichever comes first.

    A rollout's START, its first steps' messages and even its END (a halt right after the start) can
    arrive before the reset's answer that names the rollout and creates its trace. Kept: the START stamps
    of rollouts not ended yet, and the last :data:`EARLY_MESSAGES` messages and ENDs of rollouts without a
    trace (:meth:`defer`), applied in their order of arrival when the trace comes.
    """

    def __init__(self) -> None:
        self.traces: dict[int, RolloutTrace] = {}
        self._starts: dict[int, int] = {}
        self._early: deque[tuple[int, Callable[[RolloutTrace], None]]] = deque(maxlen=EARLY_MESSAGES)

    def start(self, rollout_id: int, stamp_ns: int) -> None:
        """A START event."""
        self._starts[rollout_id] = stamp_ns

    def end(self, rollout_id: int, stamp_ns: int, outcome: str) -> None:
        """An END event."""
        trace = self.traces.get(rollout_id)
        if trace is None:
            self.defer(rollout_id, lambda later: self._close(later, stamp_ns, outcome))
        else:
            self._close(trace, stamp_ns, outcome)

    def defer(self, rollout_id: int, apply: Callable[[RolloutTrace], None]) -> None:
        """A message of ``rollout_id``, which has no trace (yet): ``apply`` it to the trace :meth:`follow` brings."""
        self._early.append((rollout_id, apply))

    def follow(self, trace: RolloutTrace) -> RolloutTrace:
        """Keep ``trace`` (its rollout's first messages and END may already be here); ``trace``."""
        self.traces[trace.rollout_id] = trace
        early = [apply for rollout_id, apply in self._early if rollout_id == trace.rollout_id]
        self._early = deque(((r, a) for r, a in self._early if r != trace.rollout_id), maxlen=EARLY_MESSAGES)
        for apply in early:
            apply(trace)
        return trace

    def _close(self, trace: RolloutTrace, stamp_ns: int, outcome: str) -> None:
        trace.started_ns = self._starts.pop(trace.rollout_id, 0)
        trace.ended_ns = stamp_ns
        trace.outcome = outcome
