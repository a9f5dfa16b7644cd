"""Spinning an executor until something happened, with a timeout (shared by the DDS tests), a listener node of
the test's own, and a helper process's node until it is interrupted."""
from __future__ import annotations

import time
from collections.abc import Callable

import rclpy
from rclpy.context import Context
from rclpy.executors import Executor, ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node


def spin_until(executor: Executor, condition: Callable[[], bool], timeout: float = 10.0, step: float = 0.01) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` seconds passed; return ``condition()``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=step)
    return condition()


class Listener:
    """A node of the test's own, in its own context in ``domain``, on an executor its :meth:`spin_until` spins."""

    def __init__(self, domain: int, name: str) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node(name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        """Spin until ``condition`` holds (True) or ``timeout`` seconds passed (False)."""
        return spin_until(self.executor, condition, timeout, step=0.02)

    def close(self) -> None:
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


def spin_until_interrupted(node: Node) -> None:
    """Spin ``node`` of a helper process until SIGINT or an external shutdown; then destroy it, shut rclpy down."""
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
