"""Spinning an executor until something happened, with a timeout (shared by the DDS tests)."""
from __future__ import annotations

import time
from collections.abc import Callable

from rclpy.executors import Executor


def spin_until(executor: Executor, condition: Callable[[], bool], timeout: float = 10.0, step: float = 0.01) -> bool:
    """Spin ``executor`` until ``condition()`` holds or ``timeout`` seconds passed; return ``condition()``."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        executor.spin_once(timeout_sec=step)
    return condition()
