"""The process shell of every node (`fiper_ros.nodes.main`): shutdown while a callback runs."""
from __future__ import annotations

import threading
import time

import rclpy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor

from fiper_ros.nodes.main import spin_until_shutdown


def test_spin_until_shutdown_returns_only_after_the_callbacks_in_flight(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = rclpy.create_node("slow_callback", context=context)
    executor = MultiThreadedExecutor(num_threads=2, context=context)
    running, started = threading.Event(), threading.Event()

    def slow() -> None:  # a policy step that takes a while
        running.set()
        started.set()
        time.sleep(0.5)
        running.clear()

    node.create_timer(0.01, slow)
    executor.add_node(node)
    spinner = threading.Thread(target=spin_until_shutdown, args=(executor,))
    spinner.start()
    try:
        assert started.wait(10)
        context.try_shutdown()  # what SIGTERM does in a node process
        spinner.join(10)
        assert not spinner.is_alive()
        assert not running.is_set()  # the node may be destroyed now
    finally:
        node.destroy_node()
        rclpy.try_shutdown(context=context)
