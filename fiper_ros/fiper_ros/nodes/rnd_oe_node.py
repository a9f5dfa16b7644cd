"""RND-OE node: ObservationEmbedding -> Score on ``scores/rnd_oe`` (paper eqs. 1-3); the detector node's preset."""
from __future__ import annotations

import sys
from typing import Any

from fiper_ros.core.detectors import RND_OE
from fiper_ros.nodes.detector_node import DetectorNode
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_node, run_reported


class RndOeNode(DetectorNode):
    """Scores each observation embedding with the calibrated RND-OE model."""

    preset = RND_OE

    def __init__(self, **kwargs: Any) -> None:  # rclpy's Node kwargs
        super().__init__("rnd_oe_node", **kwargs)


#: The node class, for in-process launching.
NODE_CLASS = RndOeNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.rnd_oe_node --ros-args ...``."""
    return run_reported("rnd_oe_node", run_node, RndOeNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
