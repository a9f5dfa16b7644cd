"""The node shells' user error: what a node's command line or configuration raises."""
from __future__ import annotations

from fiper_ros.errors import FiperError


class NodeError(FiperError):
    """A node's arguments or configuration that the node refuses (a node reports a bad message, never raises)."""
