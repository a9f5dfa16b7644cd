"""Shared shell of the two scoring nodes: calibration, rollout events, step order, Score output.

A subclass says how to turn its input message into the array its core monitor scores; everything
else (rejections, missing steps, START/END, latency, the Score message) is the same for RND-OE and ACE.
"""
from __future__ import annotations

from typing import Any

from rclpy.qos_overriding_options import QoSOverridingOptions

from fiper_msgs.msg import RolloutEvent, Score
from fiper_ros.core.calibration import Calibration, load_calibration
from fiper_ros.core.monitor import StepScore
from fiper_ros.core.scores import NonFiniteScore
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.interface import qos
from fiper_ros.interface.cdr import codec
from fiper_ros.interface.messages import outcome_name
from fiper_ros.interface.topics import EVENTS, relative, score_topic
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.runtime.pending import StartGate
from fiper_ros.runtime.rollout_tracker import RolloutTracker
from fiper_ros.runtime.validation import (DEFAULT_MAX_ABS_VALUE, DEFAULT_MAX_ELEMENTS, DEFAULT_MAX_PENDING_ELEMENTS,
                                         DEFAULT_MAX_STEP_GAP, INTERNAL, NO_CALIBRATION, NON_FINITE_SCORE,
                                         TASK_MISMATCH, UNKNOWN_ROLLOUT, InputRejected)

#: The Score on the wire: the nodes publish its bytes (issue #24).
SCORE = codec(Score)


class DetectorNode(FiperNode):
    """Scores one input stream per policy step and publishes ``scores/<detector>``."""

    detector: str = ""
    input_topic: str = ""
    input_type: Any = None

    def __init__(self, name: str, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.declare_parameter("calibration_dir", "", describe("calibration directory (fiper calibrate)", read_only=True))
        self.declare_parameter("auto_start_rollouts", False,
                               describe("a message of a new rollout id starts that rollout (no RolloutEvents)"))
        self.declare_parameter("max_elements", DEFAULT_MAX_ELEMENTS,
                               describe("largest accepted array", low=1, high=1 << 30, integer=True))
        self.declare_parameter("max_abs_value", DEFAULT_MAX_ABS_VALUE,
                               describe("largest accepted magnitude of an input value", low=1.0, high=3.4e38))
        self.declare_parameter("max_step_gap", DEFAULT_MAX_STEP_GAP,
                               describe("largest accepted jump of the step number (lost steps); a bigger one is "
                                        "rejected as step_gap", read_only=True, low=0, high=1 << 31, integer=True))
        self.declare_parameter("start_wait_s", 1.0,
                               describe("how long a message may wait for its rollout's START", read_only=True,
                                        low=0.0, high=60.0))
        self.declare_parameter("start_wait_max_elements", DEFAULT_MAX_PENDING_ELEMENTS,
                               describe("largest number of values waiting for their rollout's START", read_only=True,
                                        low=1, high=1 << 32, integer=True))
        self.calibration: Calibration | None = None
        self.calibration_hash = ""
        self.monitor: Any = None
        self.rollouts = RolloutTracker(self.get_parameter("auto_start_rollouts").value,
                                       self.get_parameter("max_step_gap").value)
        self.pending: StartGate[Any] = StartGate(int(self.get_parameter("start_wait_s").value * 1e9),
                                                 max_size=self.get_parameter("start_wait_max_elements").value)
        self.published = 0
        #: STARTs of the rollout already active (ignored: its steps and windows are kept).
        self.repeated_starts = 0
        self._inputs: list[Any] = []
        score = relative(score_topic(self.detector))
        self._score_pub = self.create_lifecycle_publisher(
            Score, score, qos.SCORE_PUB, qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=self.publisher_events(score),
        )
        # Liveliness is a wall-clock contract (DDS lease): assert it on the steady clock, also under sim time.
        self.create_timer(qos.SCORE_HEARTBEAT_S, self._score_pub.assert_liveliness, clock=self.steady)
        # Events are followed in every state, so a rollout started before activation is known.
        self.create_subscription(RolloutEvent, relative(EVENTS), self._on_event, qos.EVENT,
                                 event_callbacks=self.subscription_events(relative(EVENTS)))
        self.watch_publishers()  # one publisher per input (of allowed_publishers, if set); the scores only from here

    # lifecycle ----------------------------------------------------------------------------------------
    def configure(self) -> None:
        directory = self.get_parameter("calibration_dir").value
        if not directory:
            raise ValueError("parameter calibration_dir is empty")
        directory = resolve_data_path(directory)  # relative: the working directory, the share, $FIPER_MODELS
        calibration = load_calibration(directory)
        self.monitor = self.make_monitor(calibration)
        self.calibration = calibration
        self.calibration_hash = calibration.content_hash
        self.get_logger().info(f"calibration {directory} loaded (hash {self.calibration_hash[:12]})")

    def activate(self) -> None:
        self._inputs.append(self.create_wire_subscription(
            self.input_type, self.input_topic, self._on_input, qos.INPUT,
            event_callbacks=self.subscription_events(self.input_topic),
        ))

    def deactivate(self) -> None:
        for subscription in self._inputs:
            self.destroy_subscription(subscription)
        self._inputs.clear()

    def cleanup(self) -> None:
        self.calibration = None
        self.calibration_hash = ""
        self.monitor = None

    # subclass interface -------------------------------------------------------------------------------
    def make_monitor(self, calibration: Calibration) -> Any:
        """The core streaming monitor for this detector."""
        raise NotImplementedError

    def to_array(self, msg: Any) -> Any:
        """Validate ``msg`` and return what ``score`` takes; raise InputRejected."""
        raise NotImplementedError

    def score(self, step: int, value: Any) -> StepScore:
        """Run the monitor on one validated input."""
        return self.monitor.update(step, value)

    def window(self) -> int:
        """Window size of this detector."""
        raise NotImplementedError

    # callbacks ----------------------------------------------------------------------------------------
    def _on_event(self, msg: RolloutEvent) -> None:
        if msg.event == RolloutEvent.EVENT_START:
            active = self.rollouts.active
            if active is not None and active.rollout_id == msg.rollout_id:
                self.repeated_starts += 1
                return  # already started (auto_start, or the START was repeated): keep its steps
            self.rollouts.start(msg.rollout_id, msg.task, msg.scenario, msg.max_steps)
            if self.monitor is not None:
                self.monitor.reset()
            for early in self.pending.start(msg.rollout_id):
                self._score_input(early)
        elif msg.event == RolloutEvent.EVENT_END:
            self.pending.end(msg.rollout_id)
            record = self.rollouts.end(msg.rollout_id, outcome_name(msg.outcome))
            if record is not None:
                self.get_logger().info(f"{self.detector}: {record.summary()}")

    def _on_input(self, msg: Any) -> None:
        now = self.now_ns()
        self.tick(self.input_topic, now)
        self._expire_pending(now)
        active = self.rollouts.active
        if not self.rollouts.auto_start and (active is None or active.rollout_id != msg.rollout_id) \
                and not self.pending.has_ended(msg.rollout_id):
            for dropped in self.pending.add(msg.rollout_id, msg, now, len(msg.data)):
                self._reject_unknown(dropped, "dropped from the full START wait buffer")
            return
        self._score_input(msg)

    def _expire_pending(self, now_ns: int) -> None:
        for expired in self.pending.expire(now_ns):
            self._reject_unknown(expired, "no START within start_wait_s")

    def _reject_unknown(self, msg: Any, why: str) -> None:
        self.reject(InputRejected(UNKNOWN_ROLLOUT, f"rollout {msg.rollout_id} step {msg.step}: {why}"))

    def _score_input(self, msg: Any) -> None:
        started = self.timed()
        try:
            if self.calibration is None:
                raise InputRejected(NO_CALIBRATION, "no calibration loaded")
            record, new = self.rollouts.admit(msg.rollout_id, msg.step)
        except InputRejected as error:
            self.reject(error)
            return
        if new:
            self.monitor.reset()
        self.monitor.skip_to(msg.step)  # steps that never arrived enter the window as missing
        try:
            if record.task and self.calibration.task and record.task != self.calibration.task:
                raise InputRejected(TASK_MISMATCH, f"rollout {record.rollout_id} is of task {record.task!r}, the "
                                                   f"calibration of {self.calibration.task!r}")
            result = self.score(msg.step, self.to_array(msg))
        except (InputRejected, NonFiniteScore, ValueError) as error:
            # An admitted step that cannot be scored is published as missing (NaN score, lower-bound
            # window, complete=False), so the fusion node says UNKNOWN for it aloud, never OK by silence.
            self.reject(error if isinstance(error, InputRejected) else InputRejected(
                NON_FINITE_SCORE if isinstance(error, NonFiniteScore) else INTERNAL, f"{type(error).__name__}: {error}"))
            result = self.monitor.missing(msg.step)
        latency_ms = self.record_latency(started)
        if result.exceeded and record.alarm_step is None:
            record.alarm_step = result.step
        self._score_pub.publish(SCORE.encode(SCORE.view(
            header=msg.header, rollout_id=msg.rollout_id, step=msg.step, detector=self.detector, score=result.score,
            windowed_score=result.windowed, threshold=result.threshold, exceeded=bool(result.exceeded),
            window=self.window(), complete=bool(result.complete), latency_ms=latency_ms)))
        self.published += 1

    def diagnostic_values(self) -> dict[str, str]:
        self._expire_pending(self.now_ns())
        values = {"published": str(self.published), "calibration_hash": self.calibration_hash or "none",
                  "waiting_for_start": str(len(self.pending)), "repeated_starts": str(self.repeated_starts)}
        active = self.rollouts.active
        values["active_rollout"] = "none" if active is None else str(active.rollout_id)
        return values

