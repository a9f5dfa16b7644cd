"""RND-OE node: ObservationEmbedding -> Score on ``scores/rnd_oe`` (paper eqs. 1-3)."""
from __future__ import annotations

import sys
from typing import Any

import numpy as np

from fiper_msgs.msg import ObservationEmbedding
from fiper_ros.core.calibration import Calibration
from fiper_ros.core.monitor import ObservationMonitor
from fiper_ros.interface.conversions import floats_of
from fiper_ros.interface.topics import EMBEDDING, relative
from fiper_ros.nodes.detector import DetectorNode
from fiper_ros.nodes.main import EXECUTOR_EVENTS, run_node
from fiper_ros.runtime import validation


class RndOeNode(DetectorNode):
    """Scores each observation embedding with the calibrated RND-OE model."""

    detector = "rnd_oe"
    input_topic = relative(EMBEDDING)
    input_type = ObservationEmbedding

    def __init__(self, **kwargs: Any) -> None:
        super().__init__("rnd_oe_node", **kwargs)

    def make_monitor(self, calibration: Calibration) -> ObservationMonitor:
        return ObservationMonitor(calibration)

    def window(self) -> int:
        return self.calibration.settings.window_obs if self.calibration else 0

    def to_array(self, msg: ObservationEmbedding) -> np.ndarray:
        return validation.embedding(floats_of(msg.data), msg.shape, self.calibration.embedding_dim,
                                    self.get_parameter("max_elements").value, self.get_parameter("max_abs_value").value)


#: The node class, for in-process launching.
NODE_CLASS = RndOeNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.rnd_oe_node --ros-args ...``."""
    return run_node(RndOeNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
