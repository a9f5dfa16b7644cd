"""The ``fiper`` command: one entry point for the suite's tools.

Each sub-command lives in its own module and is imported only when it runs, so ``fiper --help`` is
fast and a missing part of the environment is reported as a clear message, not a traceback. This is the one
place a user error is caught: a :class:`~fiper_ros.errors.FiperError` a command raises is printed on one line
(:func:`~fiper_ros.errors.fail`, exit status :data:`~fiper_ros.errors.EXIT_USAGE`) and a
:class:`~fiper_ros.errors.FiperWarning` on one line (:func:`~fiper_ros.errors.warn`); any other exception is a bug
and shows its traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys
import warnings
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TextIO

from fiper_ros import __version__
from fiper_ros.commands import ARGV, LABEL
from fiper_ros.errors import EXIT_USAGE, FiperError, FiperWarning, fail, warn
from fiper_ros.platform.dds import interruptible

#: name -> (module, one-line help). Each module provides ``add_arguments(parser)`` and ``run(args)``; one whose
#: ``INTERMIXED`` is true has its options parsed anywhere among its positional arguments.
COMMANDS: dict[str, tuple[str, str]] = {
    "demo": ("fiper_ros.commands.demo", "run the whole suite live on the shipped Sorting model (make demo)"),
    "doctor": ("fiper_ros.commands.doctor", "check that the workspace environment is complete"),
    "launch": ("fiper_ros.commands.launch", "start the nodes of a ROS 2 launch YAML (name:=value arguments)"),
    "echo": ("fiper_ros.commands.echo", "print the messages of a topic"),
    "record": ("fiper_ros.commands.record", "record the suite's topics into an MCAP bag"),
    "replay": ("fiper_ros.commands.replay", "play bags into the node suite and report its alarms per rollout"),
    "calibrate": ("fiper_ros.commands.calibrate", "fit a FIPER calibration on the successful rollouts of bags"),
    "collect": ("fiper_ros.commands.collect", "run a policy's closed-loop rollouts in the sim, one bag per rollout"),
    "convert": ("fiper_ros.commands.convert", "convert Sentinel or FIPER rollout data into bags"),
    "snapshot": ("fiper_ros.commands.snapshot", "black box: write a bag around every alarm rise"),
    "bag": ("fiper_ros.commands.bag", "'fiper bag recover BAG': finish a recording that did not stop cleanly"),
    "evaluate": ("fiper_ros.commands.evaluate", "evaluate FIPER and the baselines on rollout datasets"),
    "security": ("fiper_ros.commands.security", "write or check the SROS2 access-control policy of the suite's nodes"),
    "view": ("fiper_ros.commands.view", "serve the running suite live to Foxglove (WebSocket, 127.0.0.1:8765)"),
}

#: Modules whose absence means the workspace was not set up or not sourced.
_ENVIRONMENT_MODULES = {"rclpy", "fiper_msgs", "torch", "numpy", "mujoco", "pinocchio", "rosbags", "mcap", "yaml"}

NOT_SET_UP = (
    "fiper: the workspace environment is incomplete ({missing} cannot be imported).\n"
    "fiper: run 'make setup' in the repository, then '. ./env.sh' (or use bin/fiper, which sources it)."
)


@contextmanager
def warnings_of(command: list[str]) -> Iterator[None]:
    """Every :class:`~fiper_ros.errors.FiperWarning` raised inside, each time, printed by :func:`warn` as
    ``fiper COMMAND``, ``command[0]`` read when the warning comes; other warnings as Python shows them."""
    with warnings.catch_warnings():
        warnings.simplefilter("always", FiperWarning)
        shown = warnings.showwarning

        def show(message: Warning | str, category: type[Warning], filename: str, lineno: int,
                 file: TextIO | None = None, line: str | None = None) -> None:
            if issubclass(category, FiperWarning):
                warn(command[0], message)
            else:
                shown(message, category, filename, lineno, file, line)

        warnings.showwarning = show
        yield


def _load(name: str) -> tuple[Callable[[argparse.ArgumentParser], None], Callable[[argparse.Namespace], int], bool]:
    module = importlib.import_module(COMMANDS[name][0])
    return module.add_arguments, module.run, getattr(module, "INTERMIXED", False)


def build_parser() -> argparse.ArgumentParser:
    """Build the parser; sub-command options are added only for the chosen sub-command."""
    parser = argparse.ArgumentParser(prog="fiper", description="FIPER failure prediction for generative robot policies.")
    parser.add_argument("--version", action="version", version=f"fiper-ros {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name, (_, help_text) in COMMANDS.items():
        sub.add_parser(name, help=help_text, description=help_text)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Run ``fiper COMMAND ...``; return the process exit status."""
    interruptible()  # first: a Ctrl-C during the imports below stops the command
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in COMMANDS:
        build_parser().parse_args(argv)  # prints help, version or the usage error, and exits
        return EXIT_USAGE
    name = argv[0]
    label = [name]  # what the one-line reports name: ``bag recover`` once the action is parsed
    try:
        with warnings_of(label):
            add_arguments, run, intermixed = _load(name)
            sub_parser = argparse.ArgumentParser(prog=f"fiper {name}", description=COMMANDS[name][1])
            add_arguments(sub_parser)
            args = (sub_parser.parse_intermixed_args if intermixed else sub_parser.parse_args)(argv[1:])
            label[0] = getattr(args, LABEL, name)
            setattr(args, ARGV, ["fiper", *argv])
            return run(args)
    except FiperError as error:
        return fail(label[0], error)
    except ModuleNotFoundError as exc:
        top = (exc.name or "").split(".")[0]
        if top not in _ENVIRONMENT_MODULES:
            raise
        print(NOT_SET_UP.format(missing=top), file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130

if __name__ == "__main__":
    sys.exit(main())
