"""``fiper record -o BAG [TOPICS...]``: record the suite's topics into a FIPER bag.

Subscribes to the given topics (default: every topic of the bag schema, as soon as it has a
publisher) with raw subscriptions and writes the CDR bytes as received, with each connection's
offered QoS and the receive time as log time, until Ctrl-C / SIGTERM or ``--duration``. The bag is
written under a temporary name and appears complete when recording stops.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

from fiper_ros.bags.capture import InfoTracker, TopicTap
from fiper_ros.bags.errors import BagError, fail
from fiper_ros.bags.session import RosSession
from fiper_ros.bags.writer import BagWriter

#: Seconds between two looks at the ROS graph for new topics.
GRAPH_POLL_S = 0.5


def record(out: Path, topics: list[str], duration: float | None, domain: int | None, overwrite: bool) -> int:
    """Record until stopped; returns the number of messages written."""
    with RosSession("fiper_record", domain) as session:
        writer = BagWriter(out, overwrite=overwrite)
        tracker = InfoTracker(session, "fiper record")

        def sink(topic: str, msgtype: str, log_time_ns: int, raw: bytes) -> None:
            if not writer.has_topic(topic):
                writer.add_topic(topic, msgtype, tap.offered[topic])
            writer.write(topic, log_time_ns, raw)
            tracker.see(topic, msgtype, raw)

        tap = TopicTap(session, topics, sink)
        print(f"recording {', '.join(sorted(tap.wanted))} in ROS domain {session.domain} to {out} "
              f"({'Ctrl-C to stop' if duration is None else f'{duration:g} s'})", flush=True)
        try:
            started = next_poll = time.monotonic()
            while not session.stop.is_set() and (duration is None or time.monotonic() - started < duration):
                if time.monotonic() >= next_poll:
                    for topic in tap.poll():
                        print(f"  subscribed to {topic} ({tap.types[topic]})", flush=True)
                    next_poll = time.monotonic() + GRAPH_POLL_S
                session.spin_once(0.05)
        except BaseException:
            writer.abort()
            raise
        writer.info = tracker.info
        writer.close()
        return writer.count


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper record``."""
    parser.add_argument("topics", nargs="*", help="topics to record (default: the bag schema's topics)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="bag directory to create")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--domain", type=int, help="ROS domain (default: ROS_DOMAIN_ID)")
    parser.add_argument("--force", action="store_true", help="replace the bag if it exists")


def run(args: argparse.Namespace) -> int:
    """``fiper record``."""
    try:
        count = record(args.out, args.topics, args.duration, args.domain, args.force)
    except BagError as error:
        return fail("record", error)
    print(f"{args.out}: {count} messages")
    return 0
