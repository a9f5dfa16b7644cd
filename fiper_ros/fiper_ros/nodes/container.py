"""Several of the suite's nodes in one process: ``ros2 run fiper_ros container rnd_oe_node fusion_node --ros-args ...``.

The nodes are created in the order given and spun by one EventsExecutor in the process's main thread
(:func:`fiper_ros.platform.process.run_nodes`), so a message between them costs no process wake-up
(``fiper.launch.yaml compose:=true``; what that buys at PushT's shape is measured in docs/benchmarks.md, "Composed
nodes"). The price is isolation: a crash of one node ends the others, and a callback that hangs stops them all (the alarm's liveliness then lapses, which a supervisor sees; docs/nodes.md
"Composed nodes"). Every node keeps its own name, parameters (a parameter file's entries by node name, or
``/**``), lifecycle and ``/diagnostics`` status; the ``--ros-args`` reach every node, so a remap of ``__node``
without a node name before it (what a launch entry's ``name`` passes) is refused: it would give every node one
name.
"""
from __future__ import annotations

import importlib
import sys

from rclpy.utilities import remove_ros_args

from fiper_ros.nodes.errors import NodeError
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_nodes, run_reported

#: The nodes a container may hold: the suite's single-threaded nodes, each its executable's name.
NODES = ("rnd_oe_node", "ace_node", "fusion_node")


class ContainerUsageError(NodeError):
    """The container's command line names no node, an unknown one, one twice, or renames every node."""


def contained(argv: list[str]) -> list[str]:
    """The node names of a container's command line (``argv`` without the program name), checked; the
    :class:`ContainerUsageError` says what is wrong."""
    names = remove_ros_args(["container", *argv])[1:]
    if not names:
        raise ContainerUsageError(f"name the nodes to run (any of {', '.join(NODES)})")
    unknown = [name for name in names if name not in NODES]
    if unknown:
        raise ContainerUsageError(f"unknown node {unknown[0]!r} (a container holds {', '.join(NODES)})")
    if len(set(names)) != len(names):
        raise ContainerUsageError(f"a node named twice in {' '.join(names)}")
    for flag, value in zip(argv, argv[1:]):
        if flag in ("-r", "--remap") and value.startswith("__node:="):
            raise ContainerUsageError(f"'-r {value}' would name every node of the container alike: its nodes keep "
                                      "their own names (no 'name' on its launch entry)")
    return names


def node_modules(argv: list[str]) -> list[str]:
    """The modules of the nodes a container's command line (``argv`` without the program name) names, in order
    (:func:`contained`)."""
    return [f"{__package__}.{name}" for name in contained(argv)]


def node_classes(argv: list[str]) -> list[type]:
    """The classes of the nodes a container's command line names, in order (:func:`node_modules`; also what
    ``fiper launch --in-process`` builds for a container's entry)."""
    return [importlib.import_module(module).NODE_CLASS for module in node_modules(argv)]


def _run(argv: list[str]) -> int:
    return run_nodes(node_classes(argv[1:]), argv, executor=EXECUTOR_EVENTS)


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.container NODE... --ros-args ...``; a command line it refuses (before
    rclpy starts) or any other user error is one line ``container: ...``, exit status 2."""
    return run_reported("container", _run, sys.argv if args is None else args)


if __name__ == "__main__":
    sys.exit(main())
