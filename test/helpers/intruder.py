"""A process that speaks on one of the suite's topics without being the suite (``python -m helpers.intruder``):
OK alarms on the alarm topic, or below-threshold scores on a score topic, for a given rollout, every 0.1 s
(with the suite's QoS, so its data does reach the suite's subscriptions), until interrupted."""
from __future__ import annotations

import argparse
import itertools

import rclpy
from rclpy.node import Node

from fiper_msgs.msg import FailureAlarm, Score
from fiper_ros.interface import qos
from helpers.spin import spin_until_interrupted

#: The intruder's scores carry this latency, so a test can tell them from the suite's.
MARK_LATENCY_MS = 4321.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--name", required=True, help="node name")
    parser.add_argument("--namespace", default="/")
    parser.add_argument("--topic", required=True, help="fully qualified topic")
    parser.add_argument("--rollout", type=int, required=True)
    args = parser.parse_args()
    rclpy.init()
    node = Node(args.name, namespace=args.namespace)
    steps = itertools.count()
    if args.topic.endswith("/alarm"):
        publisher = node.create_publisher(FailureAlarm, args.topic, qos.ALARM_PUB)

        def tick() -> None:
            publisher.publish(FailureAlarm(rollout_id=args.rollout, step=next(steps), state=FailureAlarm.STATE_OK,
                                           reason="below thresholds", combine="and"))
    else:
        publisher = node.create_publisher(Score, args.topic, qos.SCORE_PUB)
        detector = args.topic.rsplit("/", 1)[-1]

        def tick() -> None:
            publisher.publish(Score(rollout_id=args.rollout, step=next(steps), detector=detector, score=0.0,
                                    windowed_score=0.0, threshold=1e9, exceeded=False, window=1, complete=True,
                                    latency_ms=MARK_LATENCY_MS))
    node.create_timer(0.1, tick)
    print("speaking", flush=True)
    spin_until_interrupted(node)


if __name__ == "__main__":
    main()
