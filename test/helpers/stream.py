"""The publishing side of the recorder tests: a policy's topics and the fusion node's alarm, published from the
test process over DDS as fixed CDR bytes, so that what a recorder wrote can be compared bit for bit."""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import rclpy
from helpers.suite import STEP_NS, PolicySideNode
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message

from fiper_msgs.msg import FailureAlarm, RolloutEvent
from fiper_ros.bagio.schema import normalize_cdr
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg, rollout_event_msg, to_stamp
from fiper_ros.interface.topics import ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, TOPICS


class Policy:
    """The test's publisher side: the suite-harness PolicySideNode plus a FailureAlarm publisher."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.driver = PolicySideNode(self.context)
        self.alarm = self.driver.create_publisher(FailureAlarm, "alarm", qos.ALARM)
        self.executor.add_node(self.driver)
        self._publishers = {EMBEDDING_TOPIC: self.driver.embeddings, ACTIONS_TOPIC: self.driver.batches,
                            EVENTS_TOPIC: self.driver.events, ALARM_TOPIC: self.alarm}

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not condition():
            self.executor.spin_once(timeout_sec=0.02)
        return condition()

    def subscribed(self, topics: tuple[str, ...], timeout: float = 30.0) -> bool:
        """Wait until every publisher of ``topics`` has a subscriber (a recorder matched them)."""
        return self.spin_until(lambda: all(self._publishers[t].get_subscription_count() >= 1 for t in topics), timeout)

    def publish(self, topic: str, raw: bytes) -> Sent:
        """Publish CDR bytes on ``topic``; what was sent and when (wall clock, the recorders' log time)."""
        sent = Sent(topic, raw, time.time_ns())
        self._publishers[topic].publish(raw)
        return sent

    def close(self) -> None:
        self.executor.shutdown()
        self.driver.destroy_node()
        rclpy.try_shutdown(context=self.context)


@dataclass(frozen=True)
class Sent:
    """One published message."""

    topic: str
    raw: bytes
    time_ns: int


def cdr(msg: object, topic: str) -> bytes:
    """``msg`` as the CDR bytes of its schema type, padding zeroed (the same bytes every time) and, as DDS
    sends a serialized message, padded with zeros to a multiple of 4 bytes: what a subscriber receives."""
    raw = normalize_cdr(serialize_message(msg), TOPICS[topic].msgtype)
    return raw + bytes(-len(raw) % 4)


def start_cdr(rollout_id: int) -> bytes:
    return cdr(rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, 0, task="synthetic"), EVENTS_TOPIC)


def step_cdr(rollout_id: int, step: int, rollout: Rollout) -> list[tuple[str, bytes]]:
    """The embedding and the action batch of one policy step."""
    stamp = (step + 1) * STEP_NS
    return [(EMBEDDING_TOPIC, cdr(embedding_msg(rollout_id, step, stamp, rollout.embeddings[step]), EMBEDDING_TOPIC)),
            (ACTIONS_TOPIC, cdr(action_batch_msg(rollout_id, step, stamp, rollout.actions[step], rollout.exec_steps,
                                           "ee_position"), ACTIONS_TOPIC))]


def alarm_cdr(rollout_id: int, step: int, state: int, *, heartbeat: bool = False, reason: str = "") -> bytes:
    """A FailureAlarm (latched when ALARM, as the fusion node's)."""
    alarm = FailureAlarm(rollout_id=rollout_id, step=step, state=state, latched=state == FailureAlarm.STATE_ALARM,
                         combine="and", heartbeat=heartbeat, reason=reason)
    alarm.header.stamp = to_stamp(step)
    return cdr(alarm, ALARM_TOPIC)
