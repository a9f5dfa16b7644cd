"""Running one node in its own process: init, spin, clean shutdown on SIGINT / SIGTERM."""
from __future__ import annotations

import signal
import sys
from collections.abc import Callable
from typing import Any

import rclpy
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor


def run_node(factory: Callable[..., Any], args: list[str] | None = None) -> int:
    """Create the node from ``factory`` and spin it until interrupted; returns the exit status."""
    rclpy.init(args=sys.argv if args is None else args)
    signal.signal(signal.SIGTERM, lambda *_: rclpy.try_shutdown())
    node = None
    try:
        node = factory()
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
