"""The ``fiper`` sub-commands, one module each: argument parsing and orchestration only
(:data:`fiper_ros.cli.COMMANDS` maps a name to its module, which provides ``add_arguments`` and ``run``).

:mod:`.options` holds the options several commands share; :mod:`.samples` (``python -m
fiper_ros.commands.samples``) writes the sample bags and :mod:`.policy` (``python -m fiper_ros.commands.policy``)
trains and evaluates the sim policies, outside ``fiper``.
"""
from __future__ import annotations

from fiper_ros.commands.errors import UsageError

#: A sub-command's parser may set this default (``set_defaults``) to the name its reports give, e.g. ``bag recover``.
LABEL = "fiper_command"
#: The parsed arguments carry the whole command line under this name (set by :func:`fiper_ros.cli.main`), for a file
#: that names the command that made it (``fiper evaluate --write-prior``).
ARGV = "fiper_argv"

__all__ = ["ARGV", "LABEL", "UsageError", "bag", "calibrate", "collect", "convert", "demo", "doctor", "echo", "errors", "evaluate",
           "launch", "options", "record", "replay", "samples", "security", "snapshot", "view"]
