"""``fiper bag recover PATH...``: finish unfinished bags (a recording that did not stop cleanly), in place or
into ``-o`` (:mod:`fiper_ros.bagio.recover`)."""
from __future__ import annotations

import argparse
from pathlib import Path

from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.recover import recover_bag, recover_in_place, unfinished
from fiper_ros.bagio.storage import METADATA, bag_directories
from fiper_ros.commands import LABEL


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper bag``."""
    actions = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    recover = actions.add_parser(
        "recover", help="finish unfinished bags (a recording that did not stop cleanly)",
        description="Read every complete chunk of an unfinished bag and write it as a finished rosbag2 bag "
                    "(summary, metadata.yaml); in place unless -o is given.")
    recover.add_argument("bags", nargs="+", type=Path, help="unfinished bags, or folders holding bags")
    recover.add_argument("-o", "--out", type=Path,
                         help="write the recovered bag here, leaving the unfinished one as it is (one bag only)")
    recover.add_argument("--force", action="store_true", help="replace --out if it exists")
    recover.set_defaults(**{LABEL: "bag recover"})  # the name its reports give


def run(args: argparse.Namespace) -> int:
    """``fiper bag recover``."""
    bags = bag_directories(args.bags)
    if args.out is not None and len(bags) != 1:
        raise BagError(f"-o names one bag; {len(bags)} found in {', '.join(map(str, args.bags))}")
    for bag in bags:
        if unfinished(bag) is None:
            print(f"{bag}: a finished bag, nothing to recover")
            continue
        recovery = (recover_in_place(bag) if args.out is None
                    else recover_bag(bag, args.out, overwrite=args.force))
        per_topic = ", ".join(f"{topic} {count}" for topic, count in sorted(recovery.counts.items()))
        print(f"{recovery.where()}\n  kept {recovery.chunks} complete chunk(s), {recovery.messages} messages: "
              f"{per_topic}\n  {args.out or bag}: finished (summary and {METADATA} written)", flush=True)
    return 0
