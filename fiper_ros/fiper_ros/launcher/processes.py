"""The launched suite: every node in its own OS process (:class:`ProcessGroup`) or all in this one."""
from __future__ import annotations

import contextlib
import importlib
import os
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Mapping
from datetime import datetime
from pathlib import Path
from typing import IO, Any

from fiper_ros.errors import FiperError
from fiper_ros.launcher.config import SECURITY_ENABLE_ENV, LaunchConfig, LaunchError, NodeSpec
from fiper_ros.platform.dds import PARENT_PID_ENV, STACKS_SIGNAL


#: How long a node that did not stop gets to print its stacks before it is killed.
STACKS_WAIT_S = 0.5
#: One line at a time on stdout, from the node relays and whatever else a launch prints (``--summary``).
_PRINT_LOCK = threading.Lock()


def say(line: str) -> None:
    """Print one line without interleaving with the nodes' output (one write: whole on a pipe shared with other
    processes too, however stdout is buffered)."""
    with _PRINT_LOCK:
        sys.stdout.write(line + "\n")
        sys.stdout.flush()


def launch_log_directory(env: Mapping[str, str]) -> Path:
    """Where this launch's node log files go (``output: log`` / ``both``: ``<dir>/<node name>.log``), as
    ``launch_ros``: ``$ROS_LOG_DIR``, else ``$ROS_HOME/log``, else ``~/.ros/log``, and in it one directory per
    launch named by its start time, host and launcher pid."""
    if env.get("ROS_LOG_DIR"):
        root = Path(env["ROS_LOG_DIR"])
    else:
        root = Path(env["ROS_HOME"]) / "log" if env.get("ROS_HOME") else Path.home() / ".ros" / "log"
    return root.expanduser() / f"{datetime.now():%Y-%m-%d-%H-%M-%S-%f}-{socket.gethostname()}-{os.getpid()}"


def secure_launch() -> bool:
    """Whether SROS2 security is on (:data:`SECURITY_ENABLE_ENV`): each node process then runs in its own enclave."""
    return os.environ.get(SECURITY_ENABLE_ENV, "").lower() == "true"


class ProcessGroup:
    """The launched processes, their output, their respawns and their shutdown."""

    def __init__(self, grace_s: float, params_dir: Path, log_dir: Path | None = None) -> None:
        """``params_dir``: where the nodes' name/value parameters are written as parameter files; ``log_dir``: where
        the log files of nodes with ``output: log`` or ``both`` go (default :func:`launch_log_directory`)."""
        self.grace_s = grace_s
        self.params_dir = params_dir
        self.log_dir = log_dir or launch_log_directory(os.environ)
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self.specs: dict[str, NodeSpec] = {}
        self.respawns: dict[str, int] = {}

    def say(self, line: str) -> None:
        """Print one line without interleaving with the nodes' output."""
        say(line)

    def start(self, spec: NodeSpec) -> None:
        """Start one node process and a thread relaying its output."""
        secure = secure_launch()  # then each node in its own enclave
        env = os.environ | {"PYTHONUNBUFFERED": "1", PARENT_PID_ENV: str(os.getpid())}
        proc = subprocess.Popen(spec.command(self.params_dir, enclave=secure), stdout=subprocess.PIPE,  # noqa: S603
                                stderr=subprocess.STDOUT, text=True, start_new_session=True, env=env)
        self.procs[spec.name] = proc
        self.specs[spec.name] = spec
        self.say(f"[launch] started {spec.name} (pid {proc.pid}): {spec.package}/{spec.executable} in {spec.namespace}")
        log = None
        if spec.to_log:
            path = self.log_dir / f"{spec.name}.log"
            path.parent.mkdir(parents=True, exist_ok=True)
            log = path.open("a")  # a respawned node's lines follow its earlier ones
            self.say(f"[launch] {spec.name}'s output (output: {spec.output}) goes to {path}")
        threading.Thread(target=self._relay, args=(spec, proc, log), daemon=True).start()

    def _relay(self, spec: NodeSpec, proc: subprocess.Popen[str], log: IO[str] | None) -> None:
        assert proc.stdout is not None
        try:
            for line in proc.stdout:
                if log is not None:
                    log.write(line)
                    log.flush()
                if spec.to_screen:
                    self.say(f"[{spec.name}] {line.rstrip()}")
        finally:
            if log is not None:
                log.close()

    def stop(self) -> None:
        """SIGINT every running process, SIGKILL what is left after the grace period."""
        for proc in self.procs.values():
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)
        deadline = time.monotonic() + self.grace_s
        for name, proc in self.procs.items():
            try:
                proc.wait(timeout=max(0.0, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                self.say(f"[launch] {name} did not stop within {self.grace_s:g} s: its stacks, then killing it")
                self._print_stacks(proc)
                with contextlib.suppress(ProcessLookupError):  # it may have ended meanwhile, and its group with it
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()

    @staticmethod
    def _print_stacks(proc: subprocess.Popen[str]) -> None:
        """Have a node that does not stop print where it hangs (:data:`STACKS_SIGNAL`: every thread's Python
        stack, relayed like its other output), and give it :data:`STACKS_WAIT_S` to do so (it may exit meanwhile)."""
        try:
            os.kill(proc.pid, STACKS_SIGNAL)
            proc.wait(timeout=STACKS_WAIT_S)
        except (ProcessLookupError, subprocess.TimeoutExpired):
            pass

    def watch(self, stop_event: threading.Event, required: set[str]) -> int:
        """Run until ``stop_event``, every node has exited for good, or a required node exited.

        A node with ``respawn`` is started again ``respawn_delay`` seconds after it exited, unless it has been
        respawned ``respawn_max_retries`` times already (which is said). Returns 0, or 1 if any node exited on its
        own (the others keep running unless it was required).
        """
        reported: set[str] = set()
        due: dict[str, float] = {}
        status = 0
        while not stop_event.is_set() and (len(reported) < len(self.procs) or due):
            for name, proc in self.procs.items():
                if name not in reported and proc.poll() is not None:
                    reported.add(name)
                    self.say(f"[launch] {name} exited with code {proc.returncode}")
                    status = 1
                    spec = self.specs[name]
                    if spec.respawn and name not in required:
                        respawns = self.respawns.get(name, 0)
                        if spec.may_respawn(respawns):
                            due[name] = time.monotonic() + spec.respawn_delay
                            self.say(f"[launch] respawning {name} in {spec.respawn_delay:g} s")
                        else:
                            self.say(f"[launch] not respawning {name} again: respawned {respawns} time(s), its "
                                     f"respawn_max_retries {spec.respawn_max_retries}")
            if reported & required:
                self.say(f"[launch] required node(s) {', '.join(sorted(reported & required))} exited")
                break
            for name, when in list(due.items()):
                if time.monotonic() >= when and not stop_event.is_set():
                    del due[name]
                    reported.discard(name)
                    self.respawns[name] = self.respawns.get(name, 0) + 1
                    self.start(self.specs[name])
            stop_event.wait(0.05)
        return status


def run_processes(config: LaunchConfig, grace_s: float, before_stop: Callable[[], None] | None = None) -> int:
    """Run every node in its own process until Ctrl-C / SIGTERM or until one dies (``before_stop``: called then,
    before the nodes are stopped)."""
    if secure_launch():
        for spec in config.nodes:
            _ = spec.enclave  # LaunchError before any node starts: an entry without a name has no enclave
    params_dir = tempfile.TemporaryDirectory(prefix="fiper-launch-")
    group = ProcessGroup(grace_s, Path(params_dir.name))
    stop_event = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop_event.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        for spec in config.nodes:
            group.start(spec)
        status = group.watch(stop_event, {spec.name for spec in config.nodes if spec.required})
    finally:
        if before_stop is not None:
            before_stop()
        group.say("[launch] stopping")
        group.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
        params_dir.cleanup()
    group.say("[launch] " + ", ".join(f"{n}: exit {p.returncode}" for n, p in group.procs.items()))
    return status


def build_nodes(spec: NodeSpec, context: Any = None) -> list[Any]:
    """The nodes of ``spec`` built in this process (``context``: an rclpy context, default the global one): its
    module's ``NODE_CLASS``, or the classes its ``node_classes(args)`` names (a container,
    :mod:`fiper_ros.nodes.container`), each from the ``--ros-args`` its process would get: rcl reads the same
    parameter files (wildcard entries included), parameters and remaps. ``--log-level [NAME:=]LEVEL`` (which rcl
    takes only at init) sets the level of each node's logger (or of NAME). :class:`LaunchError` for a container's
    arguments it refuses."""
    import rclpy.logging  # noqa: PLC0415 - rclpy only in-process

    module = importlib.import_module(spec.module)
    try:
        classes = module.node_classes(list(spec.arguments)) if hasattr(module, "node_classes") else [module.NODE_CLASS]
    except FiperError as error:
        raise LaunchError(f"node {spec.name}: {error}") from None
    nodes = []
    with tempfile.TemporaryDirectory(prefix="fiper-launch-") as params_dir:  # read while the nodes are made
        args = spec.ros_args(Path(params_dir))
        level = ""
        if "--log-level" in args:
            i = args.index("--log-level")
            level = args[i + 1] if i + 1 < len(args) else ""
            del args[i:i + 2]
        for node_class in classes:
            nodes.append(node_class(namespace=spec.namespace, cli_args=args, context=context))
    if level:
        name, _, severity = level.rpartition(":=")
        for node in nodes:
            rclpy.logging.set_logger_level(name or node.get_logger().name,
                                           rclpy.logging.get_logging_severity_from_string(severity))
    return nodes


def build_node(spec: NodeSpec, context: Any = None) -> Any:
    """The one node of ``spec`` built in this process (:func:`build_nodes`)."""
    (node,) = build_nodes(spec, context)
    return node


def run_in_process(config: LaunchConfig) -> int:
    """Run every node in this process on one multi-threaded executor."""
    import rclpy  # noqa: PLC0415 - only this mode needs rclpy in the launcher itself
    from rclpy.executors import MultiThreadedExecutor  # noqa: PLC0415

    from fiper_ros.platform.process import discovery_note, spin_until_shutdown, use_discovery_profile  # noqa: PLC0415

    profile = use_discovery_profile()
    if profile is not None:
        print(f"[launch] {discovery_note(profile)}", flush=True)
    rclpy.init()
    nodes = []
    try:
        executor = MultiThreadedExecutor()
        for spec in config.nodes:
            for node in build_nodes(spec):
                nodes.append(node)
                executor.add_node(node)
            print(f"[launch] {spec.name} running in-process ({spec.package}/{spec.executable})", flush=True)
        spin_until_shutdown(executor)
    except KeyboardInterrupt:  # while the nodes start
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
