"""The suite's topics and services: names, message types, the QoS their publishers offer, the Panda arm joints.

A bag records each topic with its publishers' offered QoS (docs/bags.md); the nodes, the bag tools, the
clients and the SROS2 policy (docs/security.md) all take the names from here. A topic's name ends in ``_TOPIC``, a
service's in ``_SERVICE`` (docs/architecture.md, "Names").
"""
from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.interface import qos_spec
from fiper_ros.interface.qos_spec import QosSpec

__all__ = ["ACTIONS_TOPIC", "ALARM_TOPIC", "ARM_JOINT_NAMES", "CAMERA_THIRD_TOPIC", "CAMERA_TOPICS",
           "CAMERA_WRIST_TOPIC", "CLOCK_TOPIC", "DIAGNOSTICS_TOPIC", "EMBEDDING_TOPIC", "EVENTS_TOPIC", "INPUT_TOPICS",
           "JOINT_STATES_TOPIC", "NAMESPACE", "RESET_ALARM_SERVICE", "SCORE_ACE_TOPIC", "SCORE_RND_OE_TOPIC",
           "SCORE_SPEC", "SIM_ACTION_TOPIC", "SIM_HALT_SERVICE", "SIM_PROPRIO_TOPIC", "SIM_RESET_SERVICE",
           "STEP_SIGNALS_TOPIC", "TOPICS", "TopicSpec", "input_topic", "relative", "score_topic", "topic_spec"]

#: The namespace of the suite's own topics in every shipped launch file. The scoring and fusion nodes name them
#: relative to their own namespace (:func:`relative`), so a launch in another namespace moves them together.
NAMESPACE = "/fiper"


def score_topic(detector: str) -> str:
    """The score topic of a detector (``rnd_oe``, ``ace``: :mod:`fiper_ros.core.detectors`)."""
    return f"{NAMESPACE}/scores/{detector}"


def input_topic(reads: str) -> str:
    """The topic a detector's per-step input comes on, by what it reads (:data:`fiper_ros.core.detectors.READS`:
    the elapsed time reads the embeddings' step numbers); ``KeyError`` for external scores (not in the suite)."""
    return {"embedding": EMBEDDING_TOPIC, "step": EMBEDDING_TOPIC, "actions": ACTIONS_TOPIC,
            "signal": STEP_SIGNALS_TOPIC}[reads]


def relative(topic: str) -> str:
    """A topic of the suite named relative to :data:`NAMESPACE` (``/fiper/alarm`` -> ``alarm``)."""
    prefix = f"{NAMESPACE}/"
    if not topic.startswith(prefix):
        raise ValueError(f"{topic} is not in the suite's namespace {NAMESPACE}")
    return topic.removeprefix(prefix)


EMBEDDING_TOPIC = f"{NAMESPACE}/observation_embedding"
ACTIONS_TOPIC = f"{NAMESPACE}/action_chunks"
#: A policy's named per-step signals (optional: published only by a policy that logs them).
STEP_SIGNALS_TOPIC = f"{NAMESPACE}/step_signals"
EVENTS_TOPIC = f"{NAMESPACE}/rollout_events"
SCORE_RND_OE_TOPIC = score_topic("rnd_oe")
SCORE_ACE_TOPIC = score_topic("ace")
ALARM_TOPIC = f"{NAMESPACE}/alarm"
JOINT_STATES_TOPIC = "/joint_states"
#: The sim bridge's other topics (a robot driver's): the policy's inputs and its command (the policy node's defaults).
CAMERA_WRIST_TOPIC = "/camera/wrist/image_raw"
CAMERA_THIRD_TOPIC = "/camera/third/image_raw"
CAMERA_TOPICS = (CAMERA_WRIST_TOPIC, CAMERA_THIRD_TOPIC)
SIM_PROPRIO_TOPIC = "/sim/proprio"
SIM_ACTION_TOPIC = "/sim/action"
#: ROS's simulated time (the bridge publishes it in sim-time mode, ``fiper replay`` always) and diagnostics.
CLOCK_TOPIC = "/clock"
DIAGNOSTICS_TOPIC = "/diagnostics"
#: Services: the bridge's reset (fiper_msgs/ResetRollout) and halt (std_srvs/Trigger, the supervisor's
#: default), the fusion node's own alarm reset (fiper_msgs/ResetAlarm, a private name).
SIM_RESET_SERVICE = "/sim/reset"
SIM_HALT_SERVICE = "/sim/halt"
RESET_ALARM_SERVICE = "~/reset"
#: The arm joints ACE integrates joint velocities from, picked by name from ``/joint_states``
#: (the ace_node's default ``joint_names``; the simulated Franka's arm joints).
ARM_JOINT_NAMES: tuple[str, ...] = tuple(f"panda_joint{i}" for i in range(1, 8))


@dataclass(frozen=True)
class TopicSpec:
    """One topic of the suite.

    Attributes:
        msgtype: ROS 2 type name ``pkg/msg/Name``.
        qos: The QoS the suite's publisher offers (recorded as the connection's offered QoS).
        input: True for what a policy publishes (replayed into the suite); False for the suite's outputs.
    """

    msgtype: str
    qos: QosSpec
    input: bool


TOPICS: dict[str, TopicSpec] = {
    EMBEDDING_TOPIC: TopicSpec("fiper_msgs/msg/ObservationEmbedding", qos_spec.INPUT, True),
    ACTIONS_TOPIC: TopicSpec("fiper_msgs/msg/ActionChunkBatch", qos_spec.INPUT, True),
    STEP_SIGNALS_TOPIC: TopicSpec("fiper_msgs/msg/StepSignals", qos_spec.INPUT, True),
    EVENTS_TOPIC: TopicSpec("fiper_msgs/msg/RolloutEvent", qos_spec.EVENT, True),
    SCORE_RND_OE_TOPIC: TopicSpec("fiper_msgs/msg/Score", qos_spec.SCORE_PUB, False),
    SCORE_ACE_TOPIC: TopicSpec("fiper_msgs/msg/Score", qos_spec.SCORE_PUB, False),
    ALARM_TOPIC: TopicSpec("fiper_msgs/msg/FailureAlarm", qos_spec.ALARM, False),
    JOINT_STATES_TOPIC: TopicSpec("sensor_msgs/msg/JointState", qos_spec.INPUT, True),
}
INPUT_TOPICS = tuple(name for name, spec in TOPICS.items() if spec.input)
SCORE_SPEC = TOPICS[SCORE_RND_OE_TOPIC]


def topic_spec(topic: str) -> TopicSpec:
    """The :class:`TopicSpec` of one of the suite's topics, the score topic of any detector included
    (``/fiper/scores/<detector>``); ``KeyError`` for another."""
    if topic in TOPICS:
        return TOPICS[topic]
    if topic.startswith(score_topic("")) and topic != score_topic(""):
        return SCORE_SPEC
    raise KeyError(topic)
