"""``fiper snapshot``: the black box, a bag around every alarm rise (:mod:`fiper_ros.client.snapshot`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from fiper_ros.client.snapshot import DEFAULT_MAX_MB, DEFAULT_OUT, snapshot
from fiper_ros.commands import options
from fiper_ros.commands.errors import UsageError


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper snapshot``."""
    parser.add_argument("topics", nargs="*", help="topics to keep (default: the bag schema's topics)")
    parser.add_argument("-o", "--out", type=Path, default=DEFAULT_OUT,
                        help=f"directory for the snapshot bags (default {DEFAULT_OUT})")
    parser.add_argument("--before", type=float, default=10.0, help="seconds kept before an alarm rise")
    parser.add_argument("--after", type=float, default=5.0, help="seconds recorded after an alarm rise")
    parser.add_argument("--max-mb", type=float, default=DEFAULT_MAX_MB,
                        help=f"bound of the ring buffer in MB of messages (default {DEFAULT_MAX_MB:g}); the oldest "
                             "go first")
    parser.add_argument("--duration", type=float, help="stop after this many seconds")
    parser.add_argument("--domain", type=int, help="ROS domain (default: ROS_DOMAIN_ID)")
    options.add_chunk_arguments(parser)


def run(args: argparse.Namespace) -> int:
    """``fiper snapshot``."""
    if args.before < 0 or args.after < 0 or args.max_mb <= 0:
        raise UsageError("--before and --after must be >= 0, --max-mb > 0")
    recorder = snapshot(args.out, args.topics, args.before, args.after, int(args.max_mb * 2**20),
                        options.chunks_from(args), args.duration, args.domain)
    skipped = f"; {recorder.skipped} rise(s) skipped" if recorder.skipped else ""
    print(f"{recorder.written} snapshot(s) written to {args.out}{skipped}")
    return 0
