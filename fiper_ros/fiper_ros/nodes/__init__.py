"""ROS 2 node shells of the suite: messages to arrays (:mod:`fiper_ros.interface`), the core and runtime modules,
arrays to messages. One console script per node module (``ros2 run fiper_ros NAME``).
"""
from __future__ import annotations

from fiper_ros.nodes.errors import NodeError

__all__ = ["NodeError", "ace_node", "base", "detector_node", "errors", "fusion_node", "graph_watch",
           "policy_node", "rnd_oe_node", "settings", "supervisor_node", "view_node"]
