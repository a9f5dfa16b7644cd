"""Errors of the bag tools and how the CLI reports them: one line, exit status 2, no traceback."""
from __future__ import annotations

import sys

#: Exit status of a command refused because of its input (bad bag, calibration, arguments).
EXIT_USAGE = 2


class BagError(ValueError):
    """A bag (or a file a bag command reads or writes) is missing, malformed or does not fit."""


def fail(command: str, error: object) -> int:
    """Print ``fiper COMMAND: ERROR`` on one line to stderr and return :data:`EXIT_USAGE`."""
    text = " ".join(str(error).split())
    print(f"fiper {command}: {text}", file=sys.stderr)
    return EXIT_USAGE


def warn(command: str, text: object) -> None:
    """Print ``fiper COMMAND: warning: TEXT`` on one line to stderr (the command goes on)."""
    line = " ".join(str(text).split())
    print(f"fiper {command}: warning: {line}", file=sys.stderr, flush=True)
