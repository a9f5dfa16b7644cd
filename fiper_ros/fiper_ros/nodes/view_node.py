"""View node (``fiper view``): serves the suite's topics of its namespace live on a Foxglove WebSocket
(docs/view.md).

It subscribes to ``scores/<detector>`` of each of its ``detectors`` (every detector a calibration may declare, by
default: a suite of any detector set is seen), ``alarm`` and ``rollout_events`` (relative: in its namespace),
``/diagnostics`` and the ``cameras`` (absolute), and serves each on a channel of the same name
(:mod:`fiper_ros.view.server`, bound to ``host`` = 127.0.0.1 by default): JSON with a JSON Schema for the
suite's messages and the diagnostics, ``foxglove.RawImage`` for the images, so that Foxglove's Plot, State
Transitions, Image and Diagnostics panels show them without set-up (``fiper_ros/config/foxglove/fiper.layout.json``).

It never slows the suite: it is a process of its own and only ever reads, and it subscribes to a topic only
while a client is subscribed to its channel (``on_demand``, checked every :data:`SYNC_PERIOD_S`): with nobody
watching it has no reader of the suite's topics, so no publisher of the suite sends it anything. Its
subscriptions take the raw bytes, deserialized and translated only for a client. The cameras use their own
QoS (``qos.VIEW_IMAGE``: BEST_EFFORT, the newest frame); the scores, the alarm and the events the suite's
TRANSIENT_LOCAL ones (a client that subscribes late sees the latest), every step's alarm (``qos.ALARM_EVERY``).
A client that reads slowly or not at all loses the oldest of its at most ``backlog`` queued messages; the
other clients and the node go on. The server starts once the node spins; a port that is taken ends the node
with one line naming it (exit status 2).
"""
from __future__ import annotations

import sys
from collections.abc import Callable
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.serialization import deserialize_message
from rclpy.subscription import Subscription
from sensor_msgs.msg import Image

from fiper_msgs.msg import FailureAlarm, RolloutEvent, Score
from fiper_ros.core.detectors import CALIBRATED
from fiper_ros.interface import qos
from fiper_ros.interface.topics import (ALARM_TOPIC, CAMERA_TOPICS, DIAGNOSTICS_TOPIC, EVENTS_TOPIC, relative,
                                        score_topic)
from fiper_ros.nodes.base import describe, diagnostic_array, parameter_values
from fiper_ros.nodes.settings import ViewSettings, view_settings
from fiper_ros.platform.process import run_node, run_reported
from fiper_ros.view.layout import installed_layout
from fiper_ros.view.server import DEFAULT_BACKLOG, DEFAULT_HOST, DEFAULT_PORT, HOW_TO_OPEN, ViewServer

#: The JSON topics the node serves besides the scores (relative: in its namespace), their message class and
#: subscription QoS.
JSON_TOPICS: dict[str, tuple[type, QoSProfile]] = {
    relative(ALARM_TOPIC): (FailureAlarm, qos.ALARM_EVERY),
    relative(EVENTS_TOPIC): (RolloutEvent, qos.EVENT),
    DIAGNOSTICS_TOPIC: (DiagnosticArray, qos.DIAGNOSTICS),
}
#: How often the node matches its subscriptions to the channels the clients are subscribed to (``on_demand``).
SYNC_PERIOD_S = 0.1


class ViewNode(Node):
    """Serves the suite's topics on a Foxglove WebSocket."""

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("view_node", **kwargs)
        self.declare_parameter("host", DEFAULT_HOST, describe(
            "address the WebSocket is bound to (0.0.0.0: every interface; the view has no access control)",
            read_only=True))
        self.declare_parameter("port", DEFAULT_PORT, describe("WebSocket port (0: any free port, logged)",
                                                              read_only=True, low=0, high=65535, integer=True))
        self.declare_parameter("backlog", DEFAULT_BACKLOG, describe(
            "messages queued per client; a client that does not keep up loses the oldest", read_only=True, low=1,
            high=100000, integer=True))
        self.declare_parameter("detectors", list(CALIBRATED), describe(
            "detectors whose score topics (scores/<detector>) are served; a logged signal is signal_<name>",
            read_only=True))
        self.declare_parameter("cameras", list(CAMERA_TOPICS), describe("sensor_msgs/Image topics served (absolute)",
                                                                  read_only=True))
        self.declare_parameter("diagnostics_period_s", 1.0,
                               describe("period of /diagnostics messages", read_only=True, low=0.05, high=60.0))
        self.declare_parameter("on_demand", True, describe(
            "subscribe to a topic only while a client shows it (false: to every topic from the start)",
            read_only=True))
        #: The node's settings (:class:`NodeError` naming a detector no suite scores).
        self.settings: ViewSettings = view_settings(parameter_values(self))
        self.server: ViewServer | None = None
        #: Every topic served (resolved) -> its message class and subscription QoS.
        self.streams: dict[str, tuple[type, QoSProfile]] = {
            self.resolve_topic_name(relative(score_topic(d))): (Score, qos.SCORE_SUB) for d in self.settings.detectors}
        self.streams |= {self.resolve_topic_name(name): spec for name, spec in JSON_TOPICS.items()}
        self._cameras = [self.resolve_topic_name(name) for name in self.settings.cameras]
        self.streams |= {topic: (Image, qos.VIEW_IMAGE) for topic in self._cameras}
        self._readers: dict[str, Subscription] = {}
        if not self.settings.on_demand:
            for topic in self.streams:
                self._subscribe(topic)
        self._diagnostics = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, qos.DIAGNOSTICS)
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.create_timer(self.settings.diagnostics_period_s, self._publish_diagnostics, clock=steady)
        self._start = self.create_timer(0.0, self._serve, clock=steady)
        if self.settings.on_demand:
            self.create_timer(SYNC_PERIOD_S, self._sync, clock=steady)

    def _serve(self) -> None:
        """Start the server (once, when the node first spins: building the node binds no port)."""
        self._start.cancel()
        settings = self.settings
        server = ViewServer(self.get_fully_qualified_name(), settings.host, settings.port, settings.backlog)
        for topic, (cls, _) in self.streams.items():
            if topic not in self._cameras:
                server.add_json(topic, cls)
        for topic in self._cameras:
            server.add_image(topic)
        self.server = server
        self.get_logger().info(f"serving {server.url} ({HOW_TO_OPEN}; layout {installed_layout()}): "
                               f"{', '.join(server.topics())}")

    def _subscribe(self, topic: str) -> None:
        cls, profile = self.streams[topic]
        self._readers[topic] = self.create_subscription(cls, topic, self._forward(topic, cls), profile, raw=True)

    def _sync(self) -> None:
        """Subscribe to the topics a client wants now, unsubscribe from those no client wants any more."""
        if self.server is None:
            return
        for topic in self.streams:
            wanted = self.server.wanted(topic)
            if wanted and topic not in self._readers:
                self._subscribe(topic)
            elif not wanted and topic in self._readers:
                self.destroy_subscription(self._readers.pop(topic))

    def _forward(self, topic: str, cls: type) -> Callable[[bytes], None]:
        """The raw subscription's callback of ``topic``: translate and send only what a client wants."""
        def on_message(data: bytes) -> None:
            if self.server is not None and self.server.wanted(topic):
                self.server.send(topic, deserialize_message(data, cls))
        return on_message

    def _publish_diagnostics(self) -> None:
        if self.server is None:
            level, message, values = DiagnosticStatus.WARN, "not serving yet", {}
        else:
            clients, subscriptions = self.server.clients()
            level, message = DiagnosticStatus.OK, f"serving {self.server.url}"
            values = {"url": self.server.url, "clients": str(clients), "subscriptions": str(subscriptions),
                      "topics_read": str(len(self._readers))}
            values |= {f"sent.{topic}": str(self.server.sent[topic]) for topic in self.server.topics()}
        self._diagnostics.publish(diagnostic_array(self, level, message, values))

    def destroy_node(self) -> None:
        """Stop serving, then destroy the node."""
        if self.server is not None:
            self.server.stop()
        super().destroy_node()


#: The node class, for in-process launching.
NODE_CLASS = ViewNode


def serve(args: list[str] | None = None) -> int:
    """Run the node until interrupted; :class:`~fiper_ros.view.server.ViewError` when it cannot serve,
    :class:`~fiper_ros.nodes.errors.NodeError` for a parameter it refuses."""
    return run_node(ViewNode, args)


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.view_node --ros-args -r __ns:=/fiper -p port:=8765``."""
    return run_reported("view_node", serve, args)


if __name__ == "__main__":
    sys.exit(main())
