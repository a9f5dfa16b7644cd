"""The platform's floor for ``make bench-nodes``: the suite's topology with no work.

Three node processes named as the suite's (``/fiper/rnd_oe_node``, ``/fiper/ace_node``, ``/fiper/fusion_node``), on
the suite's topics with the suite's QoS (each score publisher's and the alarm publisher's MANUAL_BY_TOPIC liveliness
asserted from a steady timer at the suite's period), each spinning the suite's executor in the suite's process shell
(:func:`fiper_ros.platform.process.run_node`) and reading and writing bytes with the wire codec, as the suite's nodes
do.
The two relays publish a Score per input with the input's header, rollout and step, nothing computed; the fusion
stand-in publishes an OK FailureAlarm once both Scores of a step have come. What the benchmark's driver measures
through them is what rclpy and Fast DDS cost on this machine for the suite's three hops (driver -> scoring node ->
fusion node -> driver): the suite's figures less these are the nodes' own work.

``python -m fiper_ros.bench.null_suite {rnd_oe,ace,fusion} [--ros-args ...]`` (the benchmark starts the three).
"""
from __future__ import annotations

import sys
from dataclasses import replace
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.utilities import remove_ros_args

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent, Score
from fiper_ros.interface import qos, qos_spec
from fiper_ros.interface.cdr import Codec, codec
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, NAMESPACE, relative,
                                        score_topic)
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_node

#: The relays, by detector: their input's type and topic (relative to :data:`NAMESPACE`, as the suite's nodes').
INPUTS: dict[str, tuple[type, str]] = {"rnd_oe": (ObservationEmbedding, relative(EMBEDDING_TOPIC)),
                                       "ace": (ActionChunkBatch, relative(ACTIONS_TOPIC))}
FUSION = "fusion"
ROLES = (*INPUTS, FUSION)
#: Steps the fusion stand-in keeps waiting for their second Score, at most (beyond, the oldest is dropped).
PENDING_MAX = 1000
#: The alarm publisher's history: as deep as the suite's fusion node's under the benchmark's override
#: (:data:`fiper_ros.bench.EVERY_ALARM`), so the driver's every-alarm reader matches the same writer.
ALARM_DEPTH = 1000


def _template(wire: Codec) -> Any:
    """A view of the message type with every field at its default (``_replace`` sets the ones that matter)."""
    return wire.decode(wire.encode(wire.msg_class()))


class _StandIn(Node):
    """A plain node named as one of the suite's, in its namespace, taking the rollout events as they do."""

    def __init__(self, name: str) -> None:
        super().__init__(name, namespace=NAMESPACE)
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_subscription(RolloutEvent, relative(EVENTS_TOPIC), self._on_event, qos.EVENT, raw=True)

    def _on_event(self, data: bytes) -> None:
        """The suite's nodes act on START and END; the stand-ins only take them."""


class Relay(_StandIn):
    """``<detector>_node``: one Score per input (its header, rollout and step), nothing computed."""

    def __init__(self, detector: str) -> None:
        super().__init__(f"{detector}_node")
        kind, topic = INPUTS[detector]
        self.detector = detector
        self._input = codec(kind)
        self._wire = codec(Score)
        self._score = _template(self._wire)._replace(detector=detector)
        self._pub = self.create_publisher(Score, relative(score_topic(detector)), qos.SCORE_PUB)
        self.create_timer(qos.SCORE_HEARTBEAT_S, self._pub.assert_liveliness, clock=self.steady)
        self.create_subscription(kind, topic, self._on_input, qos.INPUT, raw=True)

    def _on_input(self, data: bytes) -> None:
        msg = self._input.decode(data)
        self._pub.publish(self._wire.encode(self._score._replace(header=msg.header, rollout_id=msg.rollout_id,
                                                                 step=msg.step)))


class Fusion(_StandIn):
    """``fusion_node``: an OK FailureAlarm for each step once both its Scores have come."""

    def __init__(self) -> None:
        super().__init__("fusion_node")
        self._score = codec(Score)
        self._wire = codec(FailureAlarm)
        self._alarm = _template(self._wire)._replace(state=FailureAlarm.STATE_OK, combine="and")
        self._pending: dict[tuple[int, int], None] = {}
        self._pub = self.create_publisher(FailureAlarm, relative(ALARM_TOPIC),
                                          qos.profile(replace(qos_spec.ALARM_PUB, depth=ALARM_DEPTH)))
        self.create_timer(qos.ALARM_HEARTBEAT_S, self._pub.assert_liveliness, clock=self.steady)
        for detector in INPUTS:
            self.create_subscription(Score, relative(score_topic(detector)), self._on_score, qos.SCORE_SUB, raw=True)

    def _on_score(self, data: bytes) -> None:
        msg = self._score.decode(data)
        key = (msg.rollout_id, msg.step)
        if key in self._pending:
            del self._pending[key]
            self._pub.publish(self._wire.encode(self._alarm._replace(header=msg.header, rollout_id=msg.rollout_id,
                                                                     step=msg.step)))
            return
        self._pending[key] = None
        if len(self._pending) > PENDING_MAX:
            del self._pending[next(iter(self._pending))]


def stand_in(role: str) -> Node:
    """The stand-in node of ``role`` (one of :data:`ROLES`)."""
    return Fusion() if role == FUSION else Relay(role)


def main() -> int:
    """Run the stand-in its one argument names (before any ``--ros-args``)."""
    roles = remove_ros_args(sys.argv)[1:]
    if len(roles) != 1 or roles[0] not in ROLES:
        print(f"usage: python -m fiper_ros.bench.null_suite {{{','.join(ROLES)}}} [--ros-args ...]", file=sys.stderr)
        return 2
    return run_node(lambda: stand_in(roles[0]), executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
