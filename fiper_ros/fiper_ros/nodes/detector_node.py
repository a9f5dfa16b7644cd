"""A scoring node: one declared detector of a calibration, per policy step its input -> Score on
``scores/<detector>``.

One console script (``detector_node``) serves every detector a calibration may declare; its ``detector``
parameter names it, and ``rnd_oe_node`` and ``ace_node`` are its presets. What the detector reads
(:data:`fiper_ros.core.detectors.INFO`) decides the input: ``observation_embedding`` (RND-OE, logpZO,
PCA-kmeans, progress; also the step clock of the elapsed time), ``action_chunks`` (ACE, action consistency) or
``step_signals`` (a logged signal ``signal_<name>``). Everything else is the same for every detector: the
calibration's part of the rollout's task (a task the calibration never saw: its steps are published without a
threshold, so the fusion node says UNKNOWN), rejections, missing steps, START/END (:class:`RolloutGate`), latency
and the Score message.
"""
from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

from rclpy.qos_overriding_options import QoSOverridingOptions

from fiper_msgs.msg import ActionChunkBatch, ObservationEmbedding, RolloutEvent, Score, StepSignals
from fiper_ros.core.calibration import Calibration, CalibrationMismatch, load_calibration
from fiper_ros.core.detectors import SIGNAL_PREFIX
from fiper_ros.core.errors import CoreError
from fiper_ros.core.kinematics import ForwardKinematics
from fiper_ros.core.monitor import DetectorMonitor, StepScore
from fiper_ros.core.scores import NonFiniteScore
from fiper_ros.data_paths import resolve_data_path
from fiper_ros.interface import qos
from fiper_ros.interface.cdr import codec
from fiper_ros.interface.conversions import floats_of
from fiper_ros.interface.messages import outcome_name
from fiper_ros.interface.topics import EVENTS_TOPIC, input_topic, relative, score_topic
from fiper_ros.nodes.base import FiperNode, describe
from fiper_ros.nodes.errors import NodeError
from fiper_ros.nodes.settings import DetectorSettings, detector_settings
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_node, run_reported
from fiper_ros.runtime import validation
from fiper_ros.runtime.rollout_gate import RolloutGate, Route
from fiper_ros.runtime.validation import (DEFAULT_MAX_ABS_VALUE, DEFAULT_MAX_ELEMENTS, DEFAULT_MAX_PENDING_ELEMENTS,
                                         DEFAULT_MAX_STEP_GAP, INTERNAL, NO_CALIBRATION, NON_FINITE_SCORE,
                                         TASK_MISMATCH, UNKNOWN_ROLLOUT, InputRejected)

#: The Score on the wire: the nodes publish its bytes.
SCORE = codec(Score)
#: What a detector reads -> its input topic and message type.
INPUTS = {"embedding": ObservationEmbedding, "step": ObservationEmbedding, "actions": ActionChunkBatch,
          "signal": StepSignals}


class DetectorNode(FiperNode):
    """Scores one detector's input per policy step and publishes ``scores/<detector>``."""

    #: A preset's detector; ``""``: the ``detector`` parameter names it.
    preset: str = ""
    settings: DetectorSettings

    def __init__(self, name: str = "detector_node", **kwargs: Any) -> None:  # rclpy's Node kwargs
        super().__init__(name, **kwargs)
        self.declare_parameter("detector", self.preset, describe(
            "the detector scored: rnd_oe, ace, logpzo, pca_kmeans, progress, consistency, elapsed or signal_<name> "
            "(it must be declared by the calibration)", read_only=True))
        self.declare_parameter("calibration_dir", "", describe("calibration directory (fiper calibrate)", read_only=True))
        self.declare_parameter("auto_start_rollouts", False,
                               describe("a message of a new rollout id starts that rollout (no RolloutEvents)",
                                        read_only=True))
        self.declare_parameter("max_elements", DEFAULT_MAX_ELEMENTS,
                               describe("largest accepted array", read_only=True, low=1, high=1 << 30, integer=True))
        self.declare_parameter("max_abs_value", DEFAULT_MAX_ABS_VALUE,
                               describe("largest accepted magnitude of an input value", read_only=True, low=1.0,
                                        high=3.4e38))
        self.declare_parameter("max_step_gap", DEFAULT_MAX_STEP_GAP,
                               describe("largest accepted jump of the step number (lost steps); a bigger one is "
                                        "rejected as step_gap", read_only=True, low=0, high=1 << 31, integer=True))
        self.declare_parameter("start_wait_s", 1.0,
                               describe("how long a message may wait for its rollout's START", read_only=True,
                                        low=0.0, high=60.0))
        self.declare_parameter("start_wait_max_elements", DEFAULT_MAX_PENDING_ELEMENTS,
                               describe("largest number of values waiting for their rollout's START", read_only=True,
                                        low=1, high=1 << 32, integer=True))
        self.declare_preset_parameters()
        self.watch_publishers()  # one publisher per input (of allowed_publishers, if set); the scores only from here
        self.calibration: Calibration | None = None
        self.calibration_hash = ""
        self.fk: ForwardKinematics | None = None
        self.monitor: DetectorMonitor | None = None
        """The running rollout's monitor (``None``: no calibration, or a task the calibration never saw)."""
        self._monitors: dict[str, DetectorMonitor] = {}
        self.task_refusal = ""
        """Why the running rollout's task cannot be judged (``""``: it can)."""
        self.published = 0
        self._inputs: list[Any] = []
        if not self.settle(self.build_settings):
            return  # a detector no calibration can declare: nothing to score (configure says why)
        settings = self.settings
        self.gate: RolloutGate[Any] = RolloutGate(settings.auto_start_rollouts, settings.max_step_gap,
                                                  settings.start_wait_ns,
                                                  max_waiting_size=settings.start_wait_max_elements)
        score = relative(score_topic(settings.detector))
        self._score_pub = self.create_lifecycle_publisher(
            Score, score, qos.SCORE_PUB, qos_overriding_options=QoSOverridingOptions.with_default_policies(),
            event_callbacks=self.publisher_events(score))
        # Liveliness is a wall-clock contract (DDS lease): assert it on the steady clock, also under sim time.
        self.create_timer(qos.SCORE_HEARTBEAT_S, self._score_pub.assert_liveliness, clock=self.steady)
        # Events are followed in every state, so a rollout started before activation is known.
        self.create_subscription(RolloutEvent, relative(EVENTS_TOPIC), self._on_event, qos.EVENT,
                                 event_callbacks=self.subscription_events(relative(EVENTS_TOPIC)))
        self.input_topic = relative(input_topic(settings.reads))

    def declare_preset_parameters(self) -> None:
        """Declare the parameters a preset adds (:class:`AceNode`'s robot); none here."""

    @staticmethod
    def build_settings(values: Mapping[str, Any]) -> DetectorSettings:
        """The node's settings from its parameters' values (:func:`~fiper_ros.nodes.settings.detector_settings`)."""
        return detector_settings(values)

    # lifecycle ----------------------------------------------------------------------------------------
    def configure(self) -> None:
        directory = self.settings.calibration_dir
        if not directory:
            raise NodeError("parameter calibration_dir is empty")
        directory = resolve_data_path(directory)  # relative: the working directory, the share, $FIPER_MODELS
        calibration = load_calibration(directory)
        if self.settings.detector not in calibration.detectors:
            raise NodeError(f"calibration {directory} declares {', '.join(calibration.detectors)}, not "
                            f"{self.settings.detector}: nothing for {self.get_name()} to score; launch the suite of its detectors "
                            "(fiper.launch.yaml)")
        self.fk = self.forward_kinematics(calibration)
        self.calibration = calibration
        self.calibration_hash = calibration.content_hash
        self._monitors.clear()
        self.monitor = self._monitor_of(self.gate.current.task if self.gate.current else "")
        self.get_logger().info(f"{self.settings.detector}: calibration {directory} loaded (hash {self.calibration_hash[:12]})")

    def forward_kinematics(self, calibration: Calibration) -> ForwardKinematics | None:
        """The robot model the detector needs (ACE on joint-space actions: :class:`AceNode`); none here."""
        return None

    def activate(self) -> None:
        topic, msg_type = input_topic(self.settings.reads), INPUTS[self.settings.reads]
        self._inputs.append(self.create_wire_subscription(
            msg_type, relative(topic), self._on_input, qos.INPUT,
            event_callbacks=self.subscription_events(relative(topic))))

    def deactivate(self) -> None:
        for subscription in self._inputs:
            self.destroy_subscription(subscription)
        self._inputs.clear()

    def cleanup(self) -> None:
        self.calibration = None
        self.calibration_hash = ""
        self.monitor = None
        self._monitors.clear()

    # the rollout's part of the calibration ----------------------------------------------------------
    def _monitor_of(self, task: str) -> DetectorMonitor | None:
        """The monitor of ``task``'s part (one per task, kept), or ``None`` with :attr:`task_refusal` saying why."""
        self.task_refusal = ""
        if self.calibration is None:
            return None
        try:
            part = self.calibration.part(task)
        except CalibrationMismatch as error:
            self.task_refusal = f"the calibration cannot judge task {task!r}: {error}"
            return None
        key = next(name for name, own in self.calibration.tasks.items() if own is part)
        if key not in self._monitors:
            self._monitors[key] = DetectorMonitor(self.calibration, self.settings.detector, key, self.fk)
        monitor = self._monitors[key]
        monitor.reset()
        return monitor

    # input ------------------------------------------------------------------------------------------
    def to_value(self, msg: Any) -> Any:  # a message in, what the detector reads out
        """Validate ``msg`` and return what the detector reads at its step; raise InputRejected."""
        layout, settings = self.calibration.layout, self.settings
        if settings.reads == "embedding":
            return validation.embedding(floats_of(msg.data), msg.shape, layout.embedding_dim, settings.max_elements,
                                        settings.max_abs_value)
        if settings.reads == "signal":
            return validation.signal(msg.names, msg.values, settings.detector.removeprefix(SIGNAL_PREFIX),
                                     settings.max_elements, settings.max_abs_value)
        if settings.reads == "actions":
            return self.batch(msg), None
        return None  # the elapsed time reads the step alone

    def batch(self, msg: ActionChunkBatch) -> Any:  # the checked batch [B, H, D]
        """An action batch checked on its own and against the calibration's layout."""
        actions = validation.action_batch(floats_of(msg.data), msg.batch_size, msg.horizon, msg.action_dim,
                                          msg.exec_steps, self.settings.max_elements, self.settings.max_abs_value)
        layout = self.calibration.layout
        if msg.action_space != layout.action_space:
            raise InputRejected(validation.ACTION_SPACE,
                                f"action space {msg.action_space!r} != calibration's {layout.action_space!r}")
        if (msg.horizon, msg.action_dim) != (layout.horizon, layout.action_dim):
            raise InputRejected(validation.CALIBRATION_MISMATCH,
                                f"H x D = {msg.horizon} x {msg.action_dim} != calibration's {layout.horizon} x "
                                f"{layout.action_dim}")
        return actions

    # callbacks ----------------------------------------------------------------------------------------
    def _on_event(self, msg: RolloutEvent) -> None:
        if msg.event == RolloutEvent.EVENT_START:
            waited = self.gate.start(msg.rollout_id, msg.task, msg.scenario, msg.max_steps)
            if waited is None:
                return  # already started (auto_start, or the START was repeated): keep its steps
            self.monitor = self._monitor_of(msg.task)
            for early in waited:
                self._score_input(early)
        elif msg.event == RolloutEvent.EVENT_END:
            record = self.gate.end(msg.rollout_id, outcome_name(msg.outcome))
            if record is not None:
                self.get_logger().info(f"{self.settings.detector}: {record.summary()}")

    def _on_input(self, msg: Any) -> None:  # a message of the detector's input type
        now = self.now_ns()
        self.tick(self.input_topic, now)
        self._expire_waiting(now)
        if self.gate.route(msg.rollout_id) is Route.WAIT:
            for dropped in self.gate.wait(msg.rollout_id, msg, now, _size(msg)):
                self._reject_unknown(dropped, "dropped from the full START wait buffer")
            return
        self._score_input(msg)

    def _expire_waiting(self, now_ns: int) -> None:
        for expired in self.gate.expire(now_ns):
            self._reject_unknown(expired, "no START within start_wait_s")

    def _reject_unknown(self, msg: Any, why: str) -> None:
        self.reject(InputRejected(UNKNOWN_ROLLOUT, f"rollout {msg.rollout_id} step {msg.step}: {why}"))

    def _score_input(self, msg: Any) -> None:
        started = self.timed()
        try:
            if self.calibration is None:
                raise InputRejected(NO_CALIBRATION, "no calibration loaded")
            record, new = self.gate.admit(msg.rollout_id, msg.step)
        except InputRejected as error:
            self.reject(error)
            return
        if new:  # auto_start: the rollout's task is not known
            self.monitor = self._monitor_of("")
        if self.monitor is None:  # a task the calibration never saw: no threshold, so the fusion node says UNKNOWN
            self.reject(InputRejected(TASK_MISMATCH, f"rollout {record.rollout_id}: {self.task_refusal}"))
            self._publish(msg, StepScore(msg.step, float("nan"), float("nan"), float("nan"), False, False),
                          self.record_latency(started))
            return
        self.monitor.skip_to(msg.step)  # steps that never arrived enter the window as missing
        try:
            result = self.score(msg.step, self.to_value(msg))
        except (InputRejected, CoreError, ValueError) as error:
            # An admitted step that cannot be scored is published as missing (NaN score, lower-bound
            # window, complete=False), so the fusion node says UNKNOWN for it aloud, never OK by silence.
            self.reject(error if isinstance(error, InputRejected) else InputRejected(
                NON_FINITE_SCORE if isinstance(error, NonFiniteScore) else INTERNAL, f"{type(error).__name__}: {error}"))
            result = self.monitor.missing(msg.step)
        if result.exceeded and record.alarm_step is None:
            record.alarm_step = result.step
        self._publish(msg, result, self.record_latency(started))

    def score(self, step: int, value: Any) -> StepScore:
        """Run the monitor on one validated input."""
        return self.monitor.update(step, value)

    def _publish(self, msg: Any, result: StepScore, latency_ms: float) -> None:
        self._score_pub.publish(SCORE.encode(SCORE.view(
            header=msg.header, rollout_id=msg.rollout_id, step=msg.step, detector=self.settings.detector,
            score=result.score,
            windowed_score=result.windowed, threshold=result.threshold, exceeded=bool(result.exceeded),
            window=self.monitor.window if self.monitor is not None else 0, complete=bool(result.complete),
            latency_ms=latency_ms)))
        self.published += 1

    def diagnostic_values(self) -> dict[str, str]:
        if self.settings is None:
            return {}
        self._expire_waiting(self.now_ns())
        values = {"detector": self.settings.detector, "published": str(self.published),
                  "calibration_hash": self.calibration_hash or "none", "waiting_for_start": str(len(self.gate.waiting)),
                  "repeated_starts": str(self.gate.repeated_starts)}
        active = self.gate.active
        values["active_rollout"] = "none" if active is None else str(active.rollout_id)
        if self.task_refusal:
            values["task"] = self.task_refusal
        return values


def _size(msg: Any) -> int:
    """How many values a waiting message holds (what the START gate's size bound counts)."""
    for field in ("data", "values"):  # an embedding's or a batch's data (a numpy view of the wire), a signal's values
        value = getattr(msg, field, None)
        if value is not None:
            return len(value)
    return 1


#: The node class, for in-process launching.
NODE_CLASS = DetectorNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``detector_node --ros-args -p detector:=progress -r __node:=progress_node ...``."""
    return run_reported("detector_node", run_node, DetectorNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
