"""``fiper launch FILE [name:=value ...]``: start the nodes of a ROS 2 launch YAML (:mod:`fiper_ros.launcher`),
the same file ``ros2 launch`` runs, with its launch arguments set on the command line. ``--summary`` prints each
rollout's verdict as it ends and, when the launch stops, the table of TPR, TNR and detection steps
(:mod:`fiper_ros.client.verdicts`). ``--view`` is ``view:=true`` (the live view, docs/view.md) for a file that
declares it (``fiper.launch.yaml`` and what includes it), with the port checked first and the address printed."""
from __future__ import annotations

import argparse
from pathlib import Path

from fiper_ros.commands import options
from fiper_ros.core.calibration_file import CALIBRATION_FILE, CalibrationError, read_yaml, split_of
from fiper_ros.data_paths import DataPathNotFound, resolve_data_path
from fiper_ros.launcher.config import LaunchConfig, load_launch, parse_arguments
from fiper_ros.launcher.processes import run_in_process, run_processes, say
from fiper_ros.platform.dds import die_with_parent
from fiper_ros.platform.shm import clean_stale

#: Options may come after the launch arguments (``fiper launch FILE a:=1 --in-process``), as with ``ros2 launch``.
INTERMIXED = True


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper launch``."""
    parser.add_argument("file", type=Path, help="launch YAML, e.g. fiper_ros/launch/fiper.launch.yaml")
    parser.add_argument("arguments", nargs="*", metavar="name:=value", help="launch arguments (see --show-args)")
    parser.add_argument("--show-args", "-s", action="store_true", help="list the file's launch arguments and exit")
    parser.add_argument("--in-process", action="store_true", help="run all nodes in this one process")
    parser.add_argument("--grace", type=float, default=10.0, help="seconds a node gets to stop before SIGKILL")
    parser.add_argument("--summary", action="store_true",
                        help="print each rollout's verdict against its outcome and, on stop, TPR / TNR per scenario")
    options.add_view_arguments(parser)


def show_arguments(config: LaunchConfig) -> str:
    """The declared launch arguments with their descriptions, defaults and values (``--show-args``)."""
    lines = ["Arguments (pass arguments as '<name>:=<value>'):"]
    for argument in config.arguments:
        default = "(required)" if argument.default is None else f"(default: {argument.default!r})"
        choices = f" One of: {', '.join(argument.choices)}." if argument.choices else ""
        lines += [f"    '{argument.name}': {argument.description or 'no description given'}{choices}",
                  f"        {default}, here {config.values[argument.name]!r}"]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """``fiper launch``."""
    die_with_parent()  # started by a demo or a test fixture: the suite goes with it
    view = options.view_arguments(args) if not args.show_args else {}
    config = load_launch(args.file, parse_arguments(args.arguments) | view)
    if args.show_args:
        print(show_arguments(config))
        return 0
    if view:
        print(f"[launch] {options.view_banner(args.view_port)}", flush=True)
    print(f"[launch] {clean_stale().summary()}", flush=True)
    return _run(config, args)  # a LaunchError found as the nodes start: a container's arguments, an entry without enclave


def _run(config: LaunchConfig, args: argparse.Namespace) -> int:
    """Run the suite of ``config`` as ``args`` say (in processes or in this one; with the summary or without)."""
    if not args.summary:
        return run_in_process(config) if args.in_process else run_processes(config, args.grace)
    from fiper_ros.client.verdicts import LiveVerdicts  # noqa: PLC0415 - rclpy only with --summary

    verdicts = LiveVerdicts(calibration_split(config), say=say)
    verdicts.start()  # before the nodes; it reports its matches, so a policy's wait_for_suite waits for it too
    try:
        return run_in_process(config) if args.in_process else run_processes(config, args.grace, verdicts.settle)
    finally:
        verdicts.close()


def calibration_split(config: LaunchConfig) -> dict[str, object]:
    """The ``split`` record of the calibration the file's ``calibration_dir`` argument names (empty without one)."""
    directory = config.values.get("calibration_dir")
    try:
        return split_of(read_yaml(resolve_data_path(directory) / CALIBRATION_FILE)) if directory else {}
    except (CalibrationError, DataPathNotFound):
        return {}  # the nodes say what is wrong with it
