"""Publish every sample message repeatedly until interrupted (the sending side of the DDS test)."""
from __future__ import annotations

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy

from helpers.samples import sample_messages, topic_of
from helpers.spin import spin_until_interrupted


def main() -> None:
    rclpy.init()
    node = Node("fiper_sample_publisher")
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    samples = sample_messages()
    publishers = [(node.create_publisher(type(msg), topic_of(name), qos), msg) for name, msg in samples.items()]

    def tick() -> None:
        for publisher, msg in publishers:
            publisher.publish(msg)

    node.create_timer(0.1, tick)
    print("publishing", flush=True)
    spin_until_interrupted(node)


if __name__ == "__main__":
    main()
