"""``fiper echo TOPIC``: print the messages of any topic whose type is importable here.

There is no ``ros2 topic echo`` with the pip wheels. The type is taken from the ROS graph (or
``--type pkg/msg/Name``); the QoS follows the publishers' durability and reliability, so the latched
``/fiper/alarm`` is received by a late echo too. Long arrays are summarised unless ``--full``.
"""
from __future__ import annotations

import argparse
import array
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from fiper_ros.interface.messages import message_class

ARRAY_PREVIEW = 8
#: The node of ``fiper echo`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_echo"


def to_yaml_lines(msg: Any, full: bool, indent: int = 0) -> list[str]:
    """The fields of ``msg`` as YAML-like lines."""
    pad = "  " * indent
    lines = []
    for name in msg.get_fields_and_field_types():
        value = getattr(msg, name)
        if hasattr(value, "get_fields_and_field_types"):
            lines.append(f"{pad}{name}:")
            lines += to_yaml_lines(value, full, indent + 1)
        elif isinstance(value, (array.array, np.ndarray, list, tuple)) and not (value and hasattr(value[0], "get_fields_and_field_types")):
            values = list(value)
            if full or len(values) <= ARRAY_PREVIEW:
                lines.append(f"{pad}{name}: {values}")
            else:
                lines.append(f"{pad}{name}: [{', '.join(map(str, values[:ARRAY_PREVIEW]))}, ...] ({len(values)} values)")
        elif isinstance(value, (list, tuple)):
            lines.append(f"{pad}{name}:")
            for item in value:
                lines.append(f"{pad}- ")
                lines += to_yaml_lines(item, full, indent + 1)
        else:
            lines.append(f"{pad}{name}: {value!r}" if isinstance(value, str) else f"{pad}{name}: {value}")
    return lines


def subscribe(node: Any, topic: str, type_name: str, on_message: Callable[[Any], None]) -> Any:
    """Subscribe ``node`` to ``topic`` with the QoS its publishers allow: TRANSIENT_LOCAL if one is latched (so
    the latest latched message arrives), BEST_EFFORT if one is."""
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy  # noqa: PLC0415

    publishers = node.get_publishers_info_by_topic(topic)
    latched = any(p.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for p in publishers)
    best_effort = any(p.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for p in publishers)
    profile = QoSProfile(depth=10,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL if latched else DurabilityPolicy.VOLATILE,
                         reliability=ReliabilityPolicy.BEST_EFFORT if best_effort else ReliabilityPolicy.RELIABLE)
    return node.create_subscription(message_class(type_name), topic, on_message, profile)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper echo``."""
    parser.add_argument("topic", help="topic name, e.g. /fiper/alarm")
    parser.add_argument("--type", help="message type pkg/msg/Name (default: from the ROS graph)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many messages (0: never)")
    parser.add_argument("--wait", type=float, default=10.0, help="seconds to wait for the topic to appear")
    parser.add_argument("--full", action="store_true", help="print whole arrays")


def run(args: argparse.Namespace) -> int:
    """``fiper echo``."""
    import rclpy  # noqa: PLC0415
    from rclpy.executors import ExternalShutdownException  # noqa: PLC0415

    from fiper_ros.client.ros_session import enclave_args  # noqa: PLC0415

    rclpy.init(args=enclave_args(NODE_NAME))
    node = rclpy.create_node(NODE_NAME)
    try:
        type_name = args.type
        deadline = time.monotonic() + args.wait
        while type_name is None and time.monotonic() < deadline:
            found = dict(node.get_topic_names_and_types()).get(args.topic)
            type_name = found[0] if found else None
            if type_name is None:
                rclpy.spin_once(node, timeout_sec=0.1)
        if type_name is None:
            print(f"fiper echo: topic {args.topic} not found within {args.wait:g} s (give --type to wait for it)",
                  file=sys.stderr)
            return 1
        seen = 0

        def on_message(msg: Any) -> None:
            nonlocal seen
            seen += 1
            print("\n".join(to_yaml_lines(msg, args.full)) + "\n---", flush=True)

        subscribe(node, args.topic, type_name, on_message)
        while rclpy.ok() and (args.count == 0 or seen < args.count):
            rclpy.spin_once(node, timeout_sec=0.1)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
