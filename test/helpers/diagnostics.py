"""/diagnostics in a test: the latest status values of every node (:class:`DiagnosticsListener`), and whether a
node reported ACTIVE."""
from __future__ import annotations

from collections.abc import Callable, Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from fiper_ros.interface import qos
from helpers.spin import spin_until

#: The supervisor is a plain node (no lifecycle): it is up once it reports on /diagnostics.
PLAIN_NODES = ("supervisor_node",)


class DiagnosticsListener:
    """The latest /diagnostics values per status name, in the test's own context."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("test_diagnostics", context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        self.statuses: dict[str, dict[str, str]] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, qos.DIAGNOSTICS)

    def _on(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.statuses[status.name] = {kv.key: kv.value for kv in status.values}

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``condition`` holds (True) or ``timeout`` seconds passed (False)."""
        return spin_until(self.executor, condition, timeout, step=0.05)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def up(statuses: Mapping[str, Mapping[str, str]], fqn: str, name: str) -> bool:
    """Whether the node ``fqn`` reported ACTIVE (a plain node: reported at all)."""
    values = statuses.get(f"fiper: {fqn}")
    return values is not None and (name in PLAIN_NODES or values.get("lifecycle_state") == "active")
