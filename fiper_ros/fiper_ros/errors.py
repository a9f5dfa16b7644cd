"""The root of the project's user errors (docs/architecture.md, "Errors").

A :class:`FiperError` is a condition the user can fix: an input, a file, a flag, a configuration or the
environment that the code refuses, with a one-line reason. ``fiper`` (:func:`fiper_ros.cli.main`) reports
one on one line and exits 2 (a node process, :func:`fiper_ros.platform.process.run_reported`, as ``NODE: ...``).
Every package's errors derive from it through that package's own class
(``core.CoreError``, ``bagio.BagError``, ``launcher.LaunchError``, ``evaluation.EvaluationError``,
``nodes.NodeError``, ``client.ClientError``, ...). A programming error (a broken invariant, a wrong argument
of a function of this code) is an ordinary exception and is shown with its traceback. :func:`fail`, :func:`report` and
:func:`warn` print a report in one line, for ``fiper`` and for the entry points outside it
(``python -m fiper_ros.commands.policy``, the node processes).
"""
from __future__ import annotations

import sys

#: Exit status of a command refused because of its input (bad bag, calibration, arguments).
EXIT_USAGE = 2


class FiperError(Exception):
    """A refusal the user can act on: the message says in one line what is wrong and where."""


class FiperWarning(UserWarning):
    """Something the user should know while a command goes on (``fiper COMMAND: warning: ...``)."""


def one_line(text: object) -> str:
    """``text`` with every run of whitespace (newlines included) as one space: how a report shows an error."""
    return " ".join(str(text).split())


def report(label: str, error: object) -> int:
    """Print ``LABEL: ERROR`` on one line to stderr and return :data:`EXIT_USAGE` (a node process's report of a user
    error: ``fusion_node: ...``)."""
    print(f"{label}: {one_line(error)}", file=sys.stderr)
    return EXIT_USAGE


def fail(command: str, error: object) -> int:
    """Print ``fiper COMMAND: ERROR`` on one line to stderr and return :data:`EXIT_USAGE`."""
    return report(f"fiper {command}", error)


def warn(command: str, text: object) -> None:
    """Print ``fiper COMMAND: warning: TEXT`` on one line to stderr (the command goes on)."""
    print(f"fiper {command}: warning: {one_line(text)}", file=sys.stderr, flush=True)
