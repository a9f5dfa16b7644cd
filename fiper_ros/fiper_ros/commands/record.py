"""``fiper record -o BAG [TOPICS...]``: record the suite's topics into a FIPER bag (:mod:`fiper_ros.client.record`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from fiper_ros.client.record import record
from fiper_ros.commands import options


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper record``."""
    parser.add_argument("topics", nargs="*", help="topics to record (default: the bag schema's topics)")
    parser.add_argument("-o", "--out", type=Path, required=True, help="bag directory to create")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--domain", type=int, help="ROS domain (default: ROS_DOMAIN_ID)")
    parser.add_argument("--force", action="store_true", help="replace the bag if it exists")
    options.add_chunk_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """``fiper record``."""
    count = record(args.out, args.topics, args.duration, args.domain, args.force, options.chunks_from(args))
    print(f"{args.out}: {count} messages")
    return 0
