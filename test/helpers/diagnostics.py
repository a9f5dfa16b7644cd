"""/diagnostics in a test: the latest status values of every node (:class:`DiagnosticsListener`), and whether a
node reported ACTIVE."""
from __future__ import annotations

from collections.abc import Mapping

from diagnostic_msgs.msg import DiagnosticArray

from fiper_ros.interface import qos
from helpers.spin import Listener

#: The supervisor and the live view are plain nodes (no lifecycle): up once they report on /diagnostics.
PLAIN_NODES = ("supervisor_node", "view_node")


class DiagnosticsListener(Listener):
    """The latest /diagnostics values per status name, in the test's own context."""

    def __init__(self, domain: int) -> None:
        super().__init__(domain, "test_diagnostics")
        self.statuses: dict[str, dict[str, str]] = {}
        self.node.create_subscription(DiagnosticArray, "/diagnostics", self._on, qos.DIAGNOSTICS)

    def _on(self, msg: DiagnosticArray) -> None:
        for status in msg.status:
            self.statuses[status.name] = {kv.key: kv.value for kv in status.values}


def up(statuses: Mapping[str, Mapping[str, str]], fqn: str, name: str) -> bool:
    """Whether the node ``fqn`` reported ACTIVE (a plain node: reported at all)."""
    values = statuses.get(f"fiper: {fqn}")
    return values is not None and (name in PLAIN_NODES or values.get("lifecycle_state") == "active")
