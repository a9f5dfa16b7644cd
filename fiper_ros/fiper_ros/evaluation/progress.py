"""A one-line progress indicator on stderr (no dependency): ``label [#####.....] 5/10 3.2 s``."""

from __future__ import annotations

import sys
import time
from typing import TextIO


class Progress:
    """Counts finished items of a long step and redraws one stderr line; silent when disabled."""

    def __init__(self, label: str, total: int, enabled: bool = True, stream: TextIO | None = None) -> None:
        self.label = label
        self.total = max(total, 1)
        self.enabled = enabled
        self.stream = stream or sys.stderr
        self.done = 0
        self.start = time.perf_counter()

    def advance(self, count: int = 1, note: str = "") -> None:
        """Mark ``count`` more items finished and redraw."""
        self.done += count
        if self.enabled:
            filled = int(20 * self.done / self.total)
            elapsed = time.perf_counter() - self.start
            line = f"\r{self.label} [{'#' * filled}{'.' * (20 - filled)}] {self.done}/{self.total} {elapsed:.1f} s {note}"
            self.stream.write(line.ljust(79))
            self.stream.flush()

    def close(self) -> float:
        """End the line; returns the elapsed seconds."""
        elapsed = time.perf_counter() - self.start
        if self.enabled:
            self.stream.write("\n")
            self.stream.flush()
        return elapsed
