"""Spinning an executor until something happened, with a timeout (shared by the DDS tests), and a helper
process's node until it is interrupted."""
from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.executors import Executor, ExternalShutdownException
from rclpy.node import Node


def spin_until(executor: Executor, condition: Callable[[], bool], timeout: float = 10.0, step: float = 0.01) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` seconds passed; return ``condition()``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=step)
    return condition()


def spin_until_interrupted(node: Node) -> None:
    """Spin ``node`` of a helper process until SIGINT or an external shutdown; then destroy it, shut rclpy down."""
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
