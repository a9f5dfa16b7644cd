"""``fiper echo TOPIC``: print the messages of any topic whose type is importable here.

There is no ``ros2 topic echo`` with the pip wheels. The type is taken from the ROS graph (or
``--type pkg/msg/Name``); the QoS follows the publishers' durability and reliability, so the latched
``/fiper/alarm`` is received by a late echo too. Long arrays are summarised unless ``--full``.

Once its subscription has matched a publisher it says so on stderr (:func:`matched_line`): what a
publisher sends before that match is not received, beyond what a latched publisher keeps.

``--brief`` prints a FailureAlarm or a Score on one line (:class:`Printer`); ``--changes`` only the messages that
change the state: for an alarm its rollout or state (OK / ALARM / UNKNOWN; the heartbeats that repeat it and the
latched steps after the first ALARM are left out), for a score its rollout or exceedance, for any other message
its content (the header's stamp aside).
"""
from __future__ import annotations

import argparse
import array
import sys
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from fiper_ros.commands.errors import UsageError
from fiper_ros.core.detectors import info
from fiper_ros.interface.messages import AlarmStateName, message_class

ARRAY_PREVIEW = 8
#: The node of ``fiper echo`` (in the root namespace; its SROS2 enclave, docs/security.md).
NODE_NAME = "fiper_echo"
#: The message types ``--brief`` formats.
ALARM_TYPE, SCORE_TYPE = "fiper_msgs/msg/FailureAlarm", "fiper_msgs/msg/Score"


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


def matched_line(topic: str, type_name: str, publishers: int) -> str:
    """The line ``fiper echo`` writes to stderr when its subscription first matches a publisher."""
    return f"fiper echo: receiving {topic} ({type_name}) from {publishers} publisher(s)"


def alarm_brief(msg: Any) -> str:
    """A FailureAlarm on one line: rollout, step, state, the judged detectors' windowed scores against their
    thresholds (``>`` where exceeded), and why."""
    scores = [f"{info(d).label} {eta:.3f}{'>' if exceeded else '<='}{gamma:.3f}"
              for d, eta, gamma, exceeded in zip(msg.detectors, msg.eta, msg.gamma, msg.exceeded)
              if not np.isnan(gamma)]  # NaN: a state about no step
    flags = " latched" * bool(msg.latched) + " (heartbeat)" * bool(msg.heartbeat)
    state = AlarmStateName.of_code(msg.state).name
    return " ".join([f"rollout {msg.rollout_id} step {msg.step}: {state}{flags}", *scores, f"| {msg.reason}"])


def score_brief(msg: Any) -> str:
    """A Score on one line: rollout, step, detector, the step's score, the windowed score against the threshold."""
    exceeded = "exceeded" if msg.exceeded else "below"
    window = f"window {msg.window}" + ("" if msg.complete else " (incomplete)")
    return (f"rollout {msg.rollout_id} step {msg.step}: {msg.detector} score {msg.score:.3f}, windowed "
            f"{msg.windowed_score:.3f} {'>' if msg.exceeded else '<='} {msg.threshold:.3f} ({exceeded}, {window})")


BRIEF = {ALARM_TYPE: alarm_brief, SCORE_TYPE: score_brief}


class Printer:
    """What ``fiper echo`` prints for each message of a topic of ``type_name`` (``None``: nothing)."""

    def __init__(self, type_name: str, *, brief: bool = False, changes: bool = False, full: bool = False) -> None:
        if brief and type_name not in BRIEF:
            raise UsageError(f"--brief formats {' and '.join(BRIEF)}, not {type_name}")
        self.type_name, self.brief, self.changes, self.full = type_name, brief, changes, full
        self._last: object = None

    def key(self, msg: Any) -> object:
        """What a change is a change of: an alarm's rollout and state, a score's rollout, detector and exceedance,
        else the whole message but the header."""
        if self.type_name == ALARM_TYPE:
            return msg.rollout_id, msg.state
        if self.type_name == SCORE_TYPE:
            return msg.rollout_id, msg.detector, msg.exceeded
        return tuple(line for line in to_yaml_lines(msg, True) if not line.startswith(("header:", "  ")))

    def text(self, msg: Any) -> str | None:
        """The text of ``msg``, or ``None`` if ``--changes`` leaves it out."""
        if self.changes:
            key = self.key(msg)
            if key == self._last:
                return None
            self._last = key
        if self.brief:
            return BRIEF[self.type_name](msg)
        return "\n".join(to_yaml_lines(msg, self.full)) + "\n---"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper echo``."""
    parser.add_argument("topic", help="topic name, e.g. /fiper/alarm")
    parser.add_argument("--type", help="message type pkg/msg/Name (default: from the ROS graph)")
    parser.add_argument("--count", type=int, default=0, help="stop after this many messages printed (0: never)")
    parser.add_argument("--wait", type=float, default=10.0, help="seconds to wait for the topic to appear")
    parser.add_argument("--full", action="store_true", help="print whole arrays")
    parser.add_argument("--brief", action="store_true", help="one line per message (FailureAlarm, Score)")
    parser.add_argument("--changes", action="store_true",
                        help="only messages that change the state (an alarm's rollout or state, a score's exceedance)")


def run(args: argparse.Namespace) -> int:
    """``fiper echo``."""
    import rclpy  # noqa: PLC0415
    from rclpy.executors import ExternalShutdownException  # noqa: PLC0415

    from fiper_ros.client.ros_session import enclave_args  # noqa: PLC0415
    from fiper_ros.platform.process import use_discovery_profile  # noqa: PLC0415

    use_discovery_profile()
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
        printer = Printer(type_name, brief=args.brief, changes=args.changes, full=args.full)
        seen = 0

        def on_message(msg: Any) -> None:
            nonlocal seen
            text = printer.text(msg)
            if text is not None:
                seen += 1
                print(text, flush=True)

        subscription = subscribe(node, args.topic, type_name, on_message)
        matched = False
        while rclpy.ok() and (args.count == 0 or seen < args.count):
            if not matched and (publishers := subscription.get_publisher_count()) > 0:
                matched = True
                print(matched_line(args.topic, type_name, publishers), file=sys.stderr, flush=True)
            rclpy.spin_once(node, timeout_sec=0.1)
        return 0
    except (KeyboardInterrupt, ExternalShutdownException):
        return 0
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
