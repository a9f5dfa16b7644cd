"""Shell of the publisher rule (:mod:`fiper_ros.runtime.trusted_publishers`): look at the ROS graph's publishers of
a node's topics every ``period_s`` (a graph query of the local cache: about 0.1 ms per topic), judge them,
log each finding once when it appears, and tell the node (``on_change``) so that it acts at once.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from rclpy.clock import Clock, ClockType
from rclpy.node import Node

from fiper_ros.runtime.trusted_publishers import Expected, Publisher, PublisherWatch, fully_qualified

#: Key prefix of the graph's publishers of a topic in /diagnostics.
PUBLISHERS_KEY = "publishers."
#: How those values write a publisher whose node the graph does not name yet.
NOT_NAMED = "(not named yet)"


class PublisherCheck:
    """The periodic look at the graph, with the publisher counts and liveliness of the node's subscriptions."""

    def __init__(self, node: Node, expectations: Callable[[], Sequence[Expected]], period_s: float,
                 on_change: Callable[[], None] | None = None) -> None:
        self.node = node
        self.expectations = expectations
        self.on_change = on_change
        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.watch = PublisherWatch()
        #: Publishers whose liveliness lapsed, per topic, from the liveliness events of the node's subscriptions.
        self.not_alive: dict[str, int] = {}
        self.graph: dict[str, list[Publisher]] = {}
        self._matched: dict[str, int] = {}
        # The graph changes in wall time, also when the node follows a paused /clock.
        node.create_timer(period_s, self.check, clock=self.steady)

    def check(self) -> None:
        """Query the graph, judge it, call ``on_change`` if a finding appeared or went, and log it."""
        expected = self.expectations()
        self.graph = {e.topic: [Publisher(fully_qualified(info.node_namespace, info.node_name),
                                          bytes(info.endpoint_gid).hex())
                                for info in self.node.get_publishers_info_by_topic(e.topic)] for e in expected}
        self._matched = self._matched_counts()
        speaking = {topic: max(0, matched - self.not_alive[topic]) for topic, matched in self._matched.items()
                    if topic in self.not_alive}
        appeared, gone = self.watch.update(expected, self.graph, speaking, self.steady.now().nanoseconds)
        if (appeared or gone) and self.on_change is not None:
            self.on_change()  # act first, then say it
        for finding in appeared:
            self.node.get_logger().error(f"unexpected publishers: {finding}")
        for finding in gone:
            self.node.get_logger().info(f"publishers as expected again: {finding}")

    def check_if_matched(self) -> None:
        """Look again now if a subscription has matched another publisher since the last look: a publisher
        that speaks before the next periodic look is judged before its data is (a few microseconds)."""
        if self._matched_counts() != self._matched:
            self.check()

    def _matched_counts(self) -> dict[str, int]:
        return {s.topic_name: s.get_publisher_count() for s in self.node.subscriptions if s.topic_name in self.graph}

    def set_liveliness(self, topic: str, not_alive: int) -> None:
        """The publishers of ``topic`` (fully qualified) whose liveliness lapsed, from a liveliness event of the
        node's subscription: a killed publisher's lingering endpoint is then not taken for a second one."""
        self.not_alive[topic] = not_alive

    def diagnostic_values(self) -> dict[str, str]:
        """The publishers of every watched topic (``publishers.<topic>``) and the findings seen so far."""
        values = {f"{PUBLISHERS_KEY}{topic}": ",".join(p.node or NOT_NAMED for p in publishers) or "none"
                  for topic, publishers in sorted(self.graph.items())}
        return values | {"unexpected_publishers": str(len(self.watch.findings)),
                         "unexpected_publishers_seen": str(self.watch.seen)}

    def error(self) -> str:
        """The ERROR message for /diagnostics while something is unexpected; ``""`` otherwise."""
        return "unexpected publishers: " + "; ".join(map(str, self.watch.findings)) if self.watch.findings else ""
