"""The suite's topics: names, message types, the QoS their publishers offer, the Panda arm joints.

A bag records each topic with its publishers' offered QoS (docs/bags.md); the nodes, the bag tools and the
clients all take the names from here.
"""
from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.interface import qos_spec
from fiper_ros.interface.qos_spec import QosSpec

__all__ = ["ACTIONS", "ALARM", "ARM_JOINT_NAMES", "EMBEDDING", "EVENTS", "INPUT_TOPICS", "JOINT_STATES", "SCORE_ACE",
           "SCORE_RND_OE", "TOPICS", "TopicSpec"]

EMBEDDING = "/fiper/observation_embedding"
ACTIONS = "/fiper/action_chunks"
EVENTS = "/fiper/rollout_events"
SCORE_RND_OE = "/fiper/scores/rnd_oe"
SCORE_ACE = "/fiper/scores/ace"
ALARM = "/fiper/alarm"
JOINT_STATES = "/joint_states"
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
    EMBEDDING: TopicSpec("fiper_msgs/msg/ObservationEmbedding", qos_spec.INPUT, True),
    ACTIONS: TopicSpec("fiper_msgs/msg/ActionChunkBatch", qos_spec.INPUT, True),
    EVENTS: TopicSpec("fiper_msgs/msg/RolloutEvent", qos_spec.EVENT, True),
    SCORE_RND_OE: TopicSpec("fiper_msgs/msg/Score", qos_spec.SCORE_PUB, False),
    SCORE_ACE: TopicSpec("fiper_msgs/msg/Score", qos_spec.SCORE_PUB, False),
    ALARM: TopicSpec("fiper_msgs/msg/FailureAlarm", qos_spec.ALARM, False),
    JOINT_STATES: TopicSpec("sensor_msgs/msg/JointState", qos_spec.INPUT, True),
}
INPUT_TOPICS = tuple(name for name, spec in TOPICS.items() if spec.input)
