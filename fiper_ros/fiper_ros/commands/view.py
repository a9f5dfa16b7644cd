"""``fiper view``: the live view of a running suite in Foxglove (docs/view.md), the view node in this process.

It serves the suite's topics of ``--namespace`` (scores, alarm, rollout events), ``/diagnostics`` and the
cameras on a Foxglove WebSocket at ``--host``:``--port`` (127.0.0.1:8765 by default: this machine only), in the
ROS domain of this shell (``ROS_DOMAIN_ID``), until Ctrl-C. Open ``ws://HOST:PORT`` in Foxglove (Open
connection > Foxglove WebSocket) and import the layout it prints.
"""
from __future__ import annotations

import argparse

from fiper_ros.commands.errors import UsageError
from fiper_ros.core.detectors import CALIBRATED
from fiper_ros.view.server import DEFAULT_BACKLOG, DEFAULT_HOST, DEFAULT_PORT, port_problem


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Options of ``fiper view``."""
    parser.add_argument("--host", default=DEFAULT_HOST,
                        help=f"address to bind (default {DEFAULT_HOST}: this machine only; the view has no access "
                             "control, so 0.0.0.0 shows the suite to the whole network)")
    parser.add_argument("--port", type=int, default=DEFAULT_PORT, help=f"WebSocket port (default {DEFAULT_PORT}; 0: "
                                                                       "any free port, printed)")
    parser.add_argument("--namespace", default="/fiper", help="the suite's namespace (default /fiper)")
    parser.add_argument("--detectors", default=",".join(CALIBRATED), metavar="A,B,...",
                        help="detectors whose scores are served (default: every detector a calibration may declare; "
                             "a logged signal is signal_<name>)")
    parser.add_argument("--backlog", type=int, default=DEFAULT_BACKLOG,
                        help=f"messages queued per client before the oldest is dropped (default {DEFAULT_BACKLOG})")


def ros_arguments(args: argparse.Namespace) -> list[str]:
    """The view node's command line for ``args``."""
    return ["fiper view", "--ros-args", "-r", f"__ns:={args.namespace}", "-p", f"host:={args.host}",
            "-p", f"port:={args.port}", "-p", f"backlog:={args.backlog}", "-p", f"detectors:=[{args.detectors}]"]


def run(args: argparse.Namespace) -> int:
    """``fiper view``."""
    if not 0 <= args.port <= 65535 or args.backlog < 1:
        raise UsageError("--port must be in 0..65535 and --backlog >= 1")
    problem = port_problem(args.host, args.port)
    if problem:
        raise UsageError(problem)
    from fiper_ros.nodes.view_node import serve  # noqa: PLC0415 - rclpy only once the arguments are good

    return serve(ros_arguments(args))  # a ViewError if the port was taken in the meantime, a NodeError if a detector is unknown
