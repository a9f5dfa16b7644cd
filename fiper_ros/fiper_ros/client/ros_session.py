"""A private rclpy context for the bag tools: one node, one executor, the project's network rule.

The process joins ``domain`` (default: ``ROS_DOMAIN_ID`` of the environment) with discovery kept on loopback
(:func:`fiper_ros.platform.dds.local_env`) and, unless the user has a Fast DDS profile of their own, the suite's
discovery profile (:func:`fiper_ros.platform.process.use_discovery_profile`: the tool and the suite see each other
within about 0.5 s, not up to 3 s). rclpy's own signal handlers are off: SIGINT and SIGTERM set
:attr:`RosSession.stop`, so a command can finish its bag cleanly instead of dying mid-write. With
``ROS_SECURITY_ENABLE=true`` the session runs in the SROS2 enclave named as its node (``/<name>``), as the launcher
runs each node in its own (docs/security.md).
"""
from __future__ import annotations

import os
import signal
import threading
import time
from collections.abc import Callable
from types import TracebackType

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from fiper_ros.launcher.config import SECURITY_ENABLE_ENV
from fiper_ros.platform.dds import local_env
from fiper_ros.platform.process import use_discovery_profile


def environment_domain() -> int:
    """``ROS_DOMAIN_ID`` of this process (0 if unset)."""
    return int(os.environ.get("ROS_DOMAIN_ID", "0") or 0)


def enclave_args(name: str) -> list[str] | None:
    """The ROS arguments of a tool's process whose node ``name`` sits in the root namespace: its own enclave,
    ``/<name>`` (the shipped policy's), when security is on; else none."""
    if os.environ.get(SECURITY_ENABLE_ENV, "").lower() != "true":
        return None
    return ["--ros-args", "--enclave", f"/{name}"]


class RosSession:
    """rclpy context + node + executor; use as a context manager."""

    def __init__(self, name: str, domain: int | None = None) -> None:
        self.name = name
        self.domain = environment_domain() if domain is None else domain
        self.stop = threading.Event()
        self.context = Context()
        self.node: Node | None = None
        self.executor: SingleThreadedExecutor | None = None
        self._previous: dict[int, object] = {}

    def __enter__(self) -> RosSession:
        env = local_env(self.domain)
        os.environ["ROS_DOMAIN_ID"] = env["ROS_DOMAIN_ID"]
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = env["ROS_AUTOMATIC_DISCOVERY_RANGE"]
        os.environ.pop("ROS_STATIC_PEERS", None)
        if threading.current_thread() is threading.main_thread():
            self._previous = {s: signal.signal(s, lambda *_: self.stop.set()) for s in (signal.SIGINT, signal.SIGTERM)}
        use_discovery_profile()
        # No tool arguments: a tool's own (``fiper launch FILE name:=value``) are not ROS remap rules.
        rclpy.init(args=enclave_args(self.name) or [], context=self.context, domain_id=self.domain,
                   signal_handler_options=SignalHandlerOptions.NO)
        self.node = Node(self.name, context=self.context)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if self.executor is not None:
            self.executor.shutdown()
        if self.node is not None:
            self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)  # type: ignore[arg-type]

    def spin_once(self, timeout_s: float = 0.01) -> None:
        """Handle what is ready, waiting at most ``timeout_s``."""
        assert self.executor is not None
        self.executor.spin_once(timeout_sec=timeout_s)

    def spin_until(self, condition: Callable[[], bool], timeout_s: float) -> bool:
        """Spin until ``condition()`` holds, ``timeout_s`` passed, or a stop was requested."""
        deadline = time.monotonic() + timeout_s
        while not condition():
            if self.stop.is_set() or time.monotonic() >= deadline:
                return condition()
            self.spin_once(min(0.01, max(0.0, deadline - time.monotonic())))
        return True
