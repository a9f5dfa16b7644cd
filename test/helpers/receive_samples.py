"""Receive one message of every sample type and report, per type, whether it equals the sample.

Prints ``OK <type>`` or ``MISMATCH <type>`` lines and exits 0 only when every type arrived equal.
"""
from __future__ import annotations

import sys
import time

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from helpers.samples import as_plain, sample_messages, topic_of


def receive(timeout: float) -> dict[str, object]:
    """Subscribe to every sample topic and return the first message of each (within ``timeout``)."""
    samples = sample_messages()
    received: dict[str, object] = {}
    node = Node("fiper_sample_receiver")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    for name, msg in samples.items():
        node.create_subscription(type(msg), topic_of(name), lambda m, n=name: received.setdefault(n, m), qos)
    deadline = time.monotonic() + timeout
    while len(received) < len(samples) and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    node.destroy_node()
    return received


def main() -> int:
    rclpy.init()
    try:
        received = receive(float(sys.argv[1]) if len(sys.argv) > 1 else 30.0)
    finally:
        rclpy.try_shutdown()
    ok = True
    for name, msg in sample_messages().items():
        if name not in received:
            print(f"MISSING {name}", flush=True)
            ok = False
        elif as_plain(received[name]) != as_plain(msg):
            print(f"MISMATCH {name}", flush=True)
            ok = False
        else:
            print(f"OK {name}", flush=True)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
