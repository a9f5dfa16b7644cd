"""The nodes' settings: per node one frozen value of its parameters, built by one function from their plain values.

Without rclpy: a node shell reads its declared parameters once (``{name: value}``) and hands them to its builder
here, which checks what the descriptors' ranges cannot (a detector's name, a combine) and refuses a value with a
:class:`~fiper_ros.nodes.errors.NodeError` of one line naming the parameter. Every parameter is read-only
(:func:`fiper_ros.nodes.base.describe`), so the value read once is the value for the node's life. Times are kept as
the parameters give them (seconds); the nanoseconds the runtime takes are properties.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from fiper_ros.core.detectors import CALIBRATED, check_declared, info
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import Combine
from fiper_ros.nodes.errors import NodeError

#: The ``combine`` parameter's value that takes the calibration's own combine.
FROM_CALIBRATION = "calibration"
#: The detectors a detector node may be asked to score, for its refusal.
DETECTOR_NAMES = ", ".join((*CALIBRATED, "signal_<name>"))

Values = Mapping[str, Any]


def _ns(seconds: float) -> int:
    """Nanoseconds of a parameter in seconds (truncated, as the nodes always converted them)."""
    return int(seconds * 1e9)


def _names(value: Any) -> tuple[str, ...]:
    """A string-array parameter as a tuple (unset: empty; empty names left out)."""
    return tuple(str(name) for name in value or () if name)


@dataclass(frozen=True, kw_only=True)
class ShellSettings:
    """What the lifecycle shell (:class:`~fiper_ros.nodes.base.FiperNode`) of every managed node runs on; read
    when the node is built, since it drives the lifecycle itself."""

    autostart: bool
    """Walk to ACTIVE on start-up."""
    configure_retry_s: float
    """Retry period of a failed configure (with ``autostart``)."""
    diagnostics_period_s: float
    """Period of the node's /diagnostics status."""
    log_period_s: float
    """At most one log line per rejection reason in this period."""


def shell_settings(values: Values) -> ShellSettings:
    """The shell's settings from its parameters' values."""
    return ShellSettings(autostart=bool(values["autostart"]), configure_retry_s=float(values["configure_retry_s"]),
                         diagnostics_period_s=float(values["diagnostics_period_s"]),
                         log_period_s=float(values["log_period_s"]))


@dataclass(frozen=True, kw_only=True)
class DetectorSettings:
    """A scoring node's settings (:mod:`fiper_ros.nodes.detector_node`)."""

    detector: str
    """The detector scored: one a calibration may declare."""
    reads: str
    """What the detector reads (:data:`fiper_ros.core.detectors.INFO`): embedding, step, actions or signal."""
    calibration_dir: str
    """The calibration directory (``""``: none given; configure says so)."""
    auto_start_rollouts: bool
    """A message of a new rollout id starts that rollout (no RolloutEvents)."""
    max_elements: int
    """Largest accepted array."""
    max_abs_value: float
    """Largest accepted magnitude of an input value."""
    max_step_gap: int
    """Largest accepted jump of the step number."""
    start_wait_s: float
    """How long a message may wait for its rollout's START."""
    start_wait_max_elements: int
    """Largest number of values waiting for their rollout's START."""
    allowed_publishers: tuple[str, ...]
    """Nodes that may publish the node's inputs (empty: any node, one publisher per input)."""

    @property
    def start_wait_ns(self) -> int:
        """:attr:`start_wait_s` in nanoseconds."""
        return _ns(self.start_wait_s)


def _detector_fields(values: Values) -> dict[str, Any]:
    detector = str(values["detector"])
    try:
        reads = info(detector).reads if detector else ""
    except ChoiceError:
        reads = ""
    if not reads:
        raise NodeError(f"parameter detector is {detector!r}: name a detector of the calibration ({DETECTOR_NAMES})")
    return dict(detector=detector, reads=reads, calibration_dir=str(values["calibration_dir"]),
                auto_start_rollouts=bool(values["auto_start_rollouts"]), max_elements=int(values["max_elements"]),
                max_abs_value=float(values["max_abs_value"]), max_step_gap=int(values["max_step_gap"]),
                start_wait_s=float(values["start_wait_s"]),
                start_wait_max_elements=int(values["start_wait_max_elements"]),
                allowed_publishers=_names(values["allowed_publishers"]))


def detector_settings(values: Values) -> DetectorSettings:
    """A scoring node's settings; :class:`NodeError` for a ``detector`` no calibration can declare."""
    return DetectorSettings(**_detector_fields(values))


@dataclass(frozen=True, kw_only=True)
class AceSettings(DetectorSettings):
    """The ACE node's settings: a scoring node's and the robot's (:mod:`fiper_ros.nodes.ace_node`)."""

    urdf_path: str
    """Robot URDF for joint-space actions (``""``: none; a joint-space calibration then fails configure)."""
    ee_frame: str
    """End-effector frame of the URDF."""
    joint_state_topic: str
    """Measured joint positions, for joint-velocity actions."""
    joint_names: tuple[str, ...]
    """Joints of the URDF chain, picked by name from the joint states."""
    joint_state_wait_s: float
    """Longest wait of a joint-velocity batch for the joint state of its stamp."""

    @property
    def joint_state_wait_ns(self) -> int:
        """:attr:`joint_state_wait_s` in nanoseconds."""
        return _ns(self.joint_state_wait_s)


def ace_settings(values: Values) -> AceSettings:
    """The ACE node's settings (:func:`detector_settings`' refusals)."""
    return AceSettings(**_detector_fields(values), urdf_path=str(values["urdf_path"]),
                       ee_frame=str(values["ee_frame"]), joint_state_topic=str(values["joint_state_topic"]),
                       joint_names=tuple(str(name) for name in values["joint_names"]),
                       joint_state_wait_s=float(values["joint_state_wait_s"]))


@dataclass(frozen=True, kw_only=True)
class FusionSettings:
    """The fusion node's settings (:mod:`fiper_ros.nodes.fusion_node`)."""

    combine: str
    """:data:`FROM_CALIBRATION`, or a combine (``and``, ``or``, ``max``, ``kth:K``) the calibration must have."""
    calibration_dir: str
    """Calibration whose declared detectors are fused (``""``: rnd_oe and ace)."""
    deadline_s: float
    """A score stream older than this makes the state UNKNOWN (until the policy period is measured)."""
    deadline_periods: float
    """Staleness deadline in measured policy periods (0: :attr:`deadline_s`)."""
    deadline_floor_s: float
    """The period-based deadline is never shorter."""
    check_period_s: float
    """How often staleness is checked."""
    heartbeat_s: float
    """Republish the current state after this much silence."""
    buffer_size: int
    """Unmatched steps kept per rollout before eviction."""
    start_wait_s: float
    """How long a score may wait for its rollout's START."""
    allow_reset: bool
    """``~/reset`` may clear a latched alarm."""
    score_publishers: tuple[str, ...]
    """Nodes that may publish the score topics (empty: each declared detector's ``<detector>_node``)."""
    allowed_publishers: tuple[str, ...]
    """Nodes that may publish the node's other inputs (empty: any node, one publisher per input)."""

    @property
    def deadline_ns(self) -> int:
        """:attr:`deadline_s` in nanoseconds."""
        return _ns(self.deadline_s)

    @property
    def deadline_floor_ns(self) -> int:
        """:attr:`deadline_floor_s` in nanoseconds."""
        return _ns(self.deadline_floor_s)

    @property
    def heartbeat_ns(self) -> int:
        """:attr:`heartbeat_s` in nanoseconds."""
        return _ns(self.heartbeat_s)

    @property
    def start_wait_ns(self) -> int:
        """:attr:`start_wait_s` in nanoseconds."""
        return _ns(self.start_wait_s)


def fusion_settings(values: Values) -> FusionSettings:
    """The fusion node's settings; :class:`NodeError` for a ``combine`` that is neither :data:`FROM_CALIBRATION`
    nor a combine (``and``, ``or``, ``max``, ``kth:K``)."""
    combine = str(values["combine"])
    if combine != FROM_CALIBRATION:
        try:
            Combine.parse(combine)
        except ChoiceError as error:
            raise NodeError(f"parameter combine: {error}") from None
    return FusionSettings(combine=combine, calibration_dir=str(values["calibration_dir"]),
                          deadline_s=float(values["deadline_s"]), deadline_periods=float(values["deadline_periods"]),
                          deadline_floor_s=float(values["deadline_floor_s"]),
                          check_period_s=float(values["check_period_s"]), heartbeat_s=float(values["heartbeat_s"]),
                          buffer_size=int(values["buffer_size"]), start_wait_s=float(values["start_wait_s"]),
                          allow_reset=bool(values["allow_reset"]),
                          score_publishers=_names(values["score_publishers"]),
                          allowed_publishers=_names(values["allowed_publishers"]))


@dataclass(frozen=True, kw_only=True)
class PolicySettings:
    """The policy node's settings (:mod:`fiper_ros.nodes.policy_node`)."""

    model: str
    """Policy folder (policy.yaml + policy.pt), resolved as every data path."""
    batch: int
    """Action chunks sampled per step (0: the model's B)."""
    torch_threads: int
    """Torch intra-op threads."""
    start_wait_s: float
    """How long an observation may wait for its rollout's START."""
    events_topic: str
    """RolloutEvent input."""
    wrist_image_topic: str
    """Wrist camera, rgb8."""
    third_image_topic: str
    """Third-person camera, rgb8."""
    proprio_topic: str
    """Proprioception (sensor_msgs/JointState positions)."""
    embedding_topic: str
    """ObservationEmbedding output."""
    action_chunks_topic: str
    """ActionChunkBatch output."""
    action_topic: str
    """ActionCommand output (the robot's input)."""

    @property
    def start_wait_ns(self) -> int:
        """:attr:`start_wait_s` in nanoseconds."""
        return _ns(self.start_wait_s)


def policy_settings(values: Values) -> PolicySettings:
    """The policy node's settings."""
    return PolicySettings(model=str(values["model"]), batch=int(values["batch"]),
                          torch_threads=int(values["torch_threads"]), start_wait_s=float(values["start_wait_s"]),
                          **{name: str(values[name]) for name in (
                              "events_topic", "wrist_image_topic", "third_image_topic", "proprio_topic",
                              "embedding_topic", "action_chunks_topic", "action_topic")})


@dataclass(frozen=True, kw_only=True)
class SupervisorSettings:
    """The example supervisor's settings (:mod:`fiper_ros.nodes.supervisor_node`)."""

    alarm_topic: str
    """FailureAlarm topic."""
    halt_service: str
    """std_srvs/Trigger that halts the robot."""
    deadline_s: float
    """Tolerated UNKNOWN; tolerated silence while no rollout runs or its period is not measured yet."""
    silence_periods: float
    """Tolerated silence during a rollout, in measured policy periods (0: :attr:`deadline_s`)."""
    silence_floor_s: float
    """The period-based silence deadline is never shorter."""
    events_topic: str
    """RolloutEvent topic."""
    alarm_publishers: tuple[str, ...]
    """Nodes that may publish the alarm topic."""
    diagnostics_period_s: float
    """Period of /diagnostics messages."""
    halt_timeout_s: float
    """Longest wait for the halt service's reply."""
    halt_retry_s: float
    """Wait before asking again for a halt the service did not confirm."""

    @property
    def deadline_ns(self) -> int:
        """:attr:`deadline_s` in nanoseconds."""
        return _ns(self.deadline_s)

    @property
    def silence_floor_ns(self) -> int:
        """:attr:`silence_floor_s` in nanoseconds."""
        return _ns(self.silence_floor_s)

    @property
    def halt_timeout_ns(self) -> int:
        """:attr:`halt_timeout_s` in nanoseconds."""
        return _ns(self.halt_timeout_s)

    @property
    def halt_retry_ns(self) -> int:
        """:attr:`halt_retry_s` in nanoseconds."""
        return _ns(self.halt_retry_s)


def supervisor_settings(values: Values) -> SupervisorSettings:
    """The supervisor's settings."""
    return SupervisorSettings(alarm_topic=str(values["alarm_topic"]), halt_service=str(values["halt_service"]),
                              deadline_s=float(values["deadline_s"]),
                              silence_periods=float(values["silence_periods"]),
                              silence_floor_s=float(values["silence_floor_s"]),
                              events_topic=str(values["events_topic"]),
                              alarm_publishers=_names(values["alarm_publishers"]),
                              diagnostics_period_s=float(values["diagnostics_period_s"]),
                              halt_timeout_s=float(values["halt_timeout_s"]), halt_retry_s=float(values["halt_retry_s"]))


@dataclass(frozen=True, kw_only=True)
class ViewSettings:
    """The view node's settings (:mod:`fiper_ros.nodes.view_node`)."""

    host: str
    """Address the WebSocket is bound to."""
    port: int
    """WebSocket port (0: any free port)."""
    backlog: int
    """Messages queued per client."""
    detectors: tuple[str, ...]
    """Detectors whose score topics are served, each one a calibration may declare."""
    cameras: tuple[str, ...]
    """sensor_msgs/Image topics served."""
    diagnostics_period_s: float
    """Period of /diagnostics messages."""
    on_demand: bool
    """Subscribe to a topic only while a client shows it."""


def view_settings(values: Values) -> ViewSettings:
    """The view node's settings; :class:`NodeError` naming a detector of ``detectors`` no suite scores."""
    detectors = tuple(str(name) for name in values["detectors"])
    for name in detectors:
        try:
            check_declared(name)
        except ChoiceError:
            raise NodeError(f"parameter detectors: {name!r} is not a detector a suite scores ("
                            f"{', '.join(CALIBRATED)} or signal_<name>)") from None
    return ViewSettings(host=str(values["host"]), port=int(values["port"]), backlog=int(values["backlog"]),
                        detectors=detectors, cameras=tuple(str(topic) for topic in values["cameras"]),
                        diagnostics_period_s=float(values["diagnostics_period_s"]),
                        on_demand=bool(values["on_demand"]))
