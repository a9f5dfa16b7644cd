"""Capturing the suite's topics from DDS as raw CDR bytes (``fiper record`` and ``fiper snapshot``).

:class:`TopicTap` watches the ROS graph and subscribes (``raw=True``: rclpy hands over the bytes as
received) to every wanted topic once it has a publisher, with the QoS matched to its publishers as
rosbag2 does: TRANSIENT_LOCAL if every publisher offers it (so a latched alarm or rollout event
published before the tap started is captured too), RELIABLE unless a publisher is best effort.
:class:`InfoTracker` fills a bag's ``custom_data`` from what passes by.
"""
from __future__ import annotations

import sys
from collections.abc import Callable, Sequence
from dataclasses import replace
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import Qos

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.schema import BagInfo, bag_qos, typestore
from fiper_ros.client.ros_session import RosSession
from fiper_ros.interface import qos
from fiper_ros.interface.messages import message_class
from fiper_ros.interface.topics import ACTIONS_TOPIC, DIAGNOSTICS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, TOPICS
from fiper_ros.nodes.base import diagnostic_array
from fiper_ros.runtime.wiring import MATCHED_PUBLISHERS

#: Seconds between two ``/diagnostics`` reports of a tool's matches (the nodes' default period).
DIAGNOSTICS_PERIOD_S = 1.0
#: Messages a capture subscription queues before the oldest is dropped.
CAPTURE_DEPTH = 200

#: (topic, message type, receive time in ns, CDR bytes)
Sink = Callable[[str, str, int, bytes], None]


def matched_qos(publishers: Sequence[Any]) -> QoSProfile:
    """A subscription QoS every publisher in ``publishers`` (rclpy endpoint infos) is compatible with."""
    profiles = [p.qos_profile for p in publishers]
    latched = bool(profiles) and all(p.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in profiles)
    reliable = all(p.reliability == ReliabilityPolicy.RELIABLE for p in profiles)
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=CAPTURE_DEPTH,
                      reliability=ReliabilityPolicy.RELIABLE if reliable else ReliabilityPolicy.BEST_EFFORT,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE)


class TopicTap:
    """Raw subscriptions to the wanted topics as they appear.

    Args:
        session: The rclpy session.
        topics: Topics to capture; empty: every topic of the schema.
        sink: Called with every message.
    """

    def __init__(self, session: RosSession, topics: Sequence[str], sink: Sink) -> None:
        self.session = session
        self.wanted = set(topics) or set(TOPICS)
        self.sink = sink
        self.types: dict[str, str] = {}
        self.offered: dict[str, list[Qos]] = {}
        self._subscriptions: dict[str, Any] = {}
        self.skipped: set[str] = set()
        """Wanted topics left out: their type is unknown here."""

    def poll(self) -> list[str]:
        """Subscribe to wanted topics that got a publisher; returns the newly subscribed ones."""
        node = self.session.node
        new = []
        for topic, types in node.get_topic_names_and_types():
            if topic not in self.wanted or topic in self._subscriptions or topic in self.skipped:
                continue
            publishers = node.get_publishers_info_by_topic(topic)
            if not publishers:
                continue
            msgtype = types[0]
            try:
                kind = message_class(msgtype)
            except (ImportError, AttributeError, ValueError):
                kind = None
            if kind is None or msgtype not in typestore().fielddefs:
                print(f"fiper: not capturing {topic}: type {msgtype} is unknown here", file=sys.stderr)
                self.skipped.add(topic)
                continue
            self.types[topic] = msgtype
            self.offered[topic] = [bag_qos(p.qos_profile) for p in publishers]
            self._subscriptions[topic] = node.create_subscription(
                kind, topic, lambda raw, t=topic, m=msgtype: self.sink(t, m, self.now_ns(), raw),
                matched_qos(publishers), raw=True)
            new.append(topic)
        return new

    def matched_publishers(self) -> dict[str, int]:
        """Per wanted topic, how many publishers its subscription has matched: 0 while not subscribed yet (a
        policy waits for it), those of an unknown type left out."""
        counts = dict.fromkeys(sorted(self.wanted - self.skipped), 0)
        return counts | {topic: sub.get_publisher_count() for topic, sub in self._subscriptions.items()}

    def now_ns(self) -> int:
        """Receive time stamp: the node clock."""
        return self.session.node.get_clock().now().nanoseconds


class InfoTracker:
    """``custom_data`` of a captured bag: shapes and task from the first messages, the calibration hash
    from the scoring nodes' ``/diagnostics``."""

    def __init__(self, session: RosSession, source: str) -> None:
        self.info = BagInfo(source=source)
        session.node.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, self._on_diagnostics, qos.DIAGNOSTICS)

    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            for value in status.values:
                if value.key == "calibration_hash" and value.value not in ("", "none"):
                    self.info = replace(self.info, calibration_hash=value.value)

    def see(self, topic: str, msgtype: str, raw: bytes) -> None:
        """Learn from one captured message (decodes only what is still unknown)."""
        info = self.info
        if topic == EMBEDDING_TOPIC and not info.embedding_dim:
            msg = typestore().deserialize_cdr(raw, msgtype)
            self.info = replace(info, embedding_dim=int(msg.data.size))
        elif topic == ACTIONS_TOPIC and not info.action_dim:
            msg = typestore().deserialize_cdr(raw, msgtype)
            self.info = replace(info, batch_size=int(msg.batch_size), horizon=int(msg.horizon),
                                action_dim=int(msg.action_dim), exec_steps=int(msg.exec_steps),
                                action_space=str(msg.action_space))
        elif topic == EVENTS_TOPIC and not info.task:
            msg = typestore().deserialize_cdr(raw, msgtype)
            if msg.event == RolloutEvent.EVENT_START and msg.task:
                self.info = replace(info, task=str(msg.task))


def report_matches(node: Node, matched: Callable[[], dict[str, int]]) -> None:
    """Publish on ``/diagnostics``, every :data:`DIAGNOSTICS_PERIOD_S` while ``node`` is spun, how many publishers
    each subscription of a tool's node has matched (``matched()``: per topic), under the keys the suite's nodes
    use (:data:`~fiper_ros.runtime.wiring.MATCHED_PUBLISHERS`): a policy waits for such a reader too
    (:meth:`fiper_ros.publishing.FiperPublisher.wait_for_suite`)."""
    publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS)

    def report() -> None:
        counts = matched()
        values = {f"{MATCHED_PUBLISHERS}{topic}": str(count) for topic, count in sorted(counts.items())}
        publisher.publish(diagnostic_array(node, DiagnosticStatus.OK, f"reading {len(counts)} topics", values))

    node.create_timer(DIAGNOSTICS_PERIOD_S, report)
