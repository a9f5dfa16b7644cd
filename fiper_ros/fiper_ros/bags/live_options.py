"""How a live bag goes to disk (:class:`LiveChunks`, ``fiper record`` and ``fiper snapshot``: ``--chunk-s``,
``--chunk-mb``), i.e. how much a crash can lose, and whether a reading command takes an unfinished bag
(``--strict`` of ``fiper replay``, ``calibrate`` and ``evaluate``). No heavy imports: ``fiper evaluate``
reads its options without the ROS message build."""
from __future__ import annotations

import argparse
from dataclasses import dataclass

from fiper_ros.bags.errors import BagError

#: Default of ``--chunk-s``: a live bag's open chunk is written at least this often.
DEFAULT_CHUNK_S = 1.0
#: Default of ``--chunk-mb`` and the chunk size of staged bags (``rosbags``' own choice, 1 MiB).
DEFAULT_CHUNK_MB = 1.0


@dataclass(frozen=True)
class LiveChunks:
    """How often a live bag's open chunk goes to disk: after ``seconds`` or ``megabytes`` of messages."""

    seconds: float = DEFAULT_CHUNK_S
    megabytes: float = DEFAULT_CHUNK_MB

    def __post_init__(self) -> None:
        if not (self.seconds > 0 and self.megabytes > 0):
            raise BagError(f"--chunk-s and --chunk-mb must be > 0 (got {self.seconds:g} and {self.megabytes:g})")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--chunk-s`` and ``--chunk-mb``."""
    parser.add_argument("--chunk-s", type=float, default=DEFAULT_CHUNK_S,
                        help=f"write the open chunk to disk at least this often, seconds (default {DEFAULT_CHUNK_S:g}; "
                             "a crash loses at most this much)")
    parser.add_argument("--chunk-mb", type=float, default=DEFAULT_CHUNK_MB,
                        help=f"... or once it holds this many MB of messages (default {DEFAULT_CHUNK_MB:g})")


def chunks_from(args: argparse.Namespace) -> LiveChunks:
    """The chunking of the command line (:class:`~fiper_ros.bags.errors.BagError` unless both are > 0)."""
    return LiveChunks(args.chunk_s, args.chunk_mb)


def add_strict_argument(parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
    """``--strict``: refuse an unfinished bag instead of reading it up to its last complete chunk."""
    parser.add_argument("--strict", action="store_true",
                        help="refuse an unfinished bag (a recording that did not stop cleanly) instead of reading "
                             "it up to its last complete chunk with a warning")
