"""How a live bag goes to disk (:class:`LiveChunks`; ``fiper record`` and ``fiper snapshot``'s ``--chunk-s``,
``--chunk-mb``, :mod:`fiper_ros.commands.options`), i.e. how much a crash can lose."""
from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.bagio.errors import BagError

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
