"""The launched suite: every node in its own OS process (:class:`ProcessGroup`) or all in this one."""
from __future__ import annotations

import importlib
import os
import signal
import subprocess
import sys
import threading
import time
from typing import Any

import yaml

from fiper_ros.dds import PARENT_PID_ENV
from fiper_ros.launcher.config import LaunchConfig, NodeSpec, SECURITY_ENABLE_ENV


class ProcessGroup:
    """The launched processes, their output, their respawns and their shutdown."""

    def __init__(self, grace_s: float, use_sim_time: bool = False) -> None:
        self.grace_s = grace_s
        self.use_sim_time = use_sim_time
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self.specs: dict[str, NodeSpec] = {}
        self.respawns: dict[str, int] = {}
        self._print_lock = threading.Lock()

    def say(self, line: str) -> None:
        """Print one line without interleaving with the nodes' output."""
        with self._print_lock:
            print(line, flush=True)

    def start(self, spec: NodeSpec, use_sim_time: bool | None = None) -> None:
        """Start one node process and a thread relaying its output."""
        if use_sim_time is not None:
            self.use_sim_time = use_sim_time
        secure = os.environ.get(SECURITY_ENABLE_ENV, "").lower() == "true"  # then each node in its own enclave
        cmd = [sys.executable, "-m", spec.module, *spec.ros_args(self.use_sim_time, enclave=secure)]
        env = os.environ | {"PYTHONUNBUFFERED": "1", PARENT_PID_ENV: str(os.getpid())}
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,  # noqa: S603
                                start_new_session=True, env=env)
        self.procs[spec.name] = proc
        self.specs[spec.name] = spec
        self.say(f"[launch] started {spec.name} (pid {proc.pid}): {spec.module} in {spec.namespace}")
        threading.Thread(target=self._relay, args=(spec.name, proc), daemon=True).start()

    def _relay(self, name: str, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            self.say(f"[{name}] {line.rstrip()}")

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
                self.say(f"[launch] {name} did not stop within {self.grace_s:g} s: killing it")
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()

    def watch(self, stop_event: threading.Event, required: set[str]) -> int:
        """Run until ``stop_event``, every node has exited for good, or a required node exited.

        A node with ``respawn`` is started again ``respawn_delay`` seconds after it exited. Returns 0, or 1
        if any node exited on its own (the others keep running unless it was required).
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
                        due[name] = time.monotonic() + spec.respawn_delay
                        self.say(f"[launch] respawning {name} in {spec.respawn_delay:g} s")
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


def run_processes(config: LaunchConfig, grace_s: float) -> int:
    """Run every node in its own process until Ctrl-C / SIGTERM or until one dies."""
    group = ProcessGroup(grace_s, config.use_sim_time)
    stop_event = threading.Event()
    previous = {sig: signal.signal(sig, lambda *_: stop_event.set()) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        for spec in config.nodes:
            group.start(spec)
        status = group.watch(stop_event, {spec.name for spec in config.nodes if spec.required})
    finally:
        group.say("[launch] stopping")
        group.stop()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    group.say("[launch] " + ", ".join(f"{n}: exit {p.returncode}" for n, p in group.procs.items()))
    return status


def build_node(spec: NodeSpec, use_sim_time: bool, context: Any = None) -> Any:
    """The node of ``spec`` built in this process (``context``: an rclpy context, default the global one),
    with the parameters its process would get: the parameter files' entries for it, then its inline ones."""
    from rclpy.parameter import Parameter, parameter_dict_from_yaml_file  # noqa: PLC0415 - rclpy only in-process

    overrides: dict[str, Parameter] = {}
    for file in spec.parameter_files:
        if spec.fqn not in (yaml.safe_load(file.read_text()) or {}):
            continue  # a shared file without an entry for this node (nodes.yaml and the sim bridge)
        overrides |= {name: Parameter.from_parameter_msg(msg)
                      for name, msg in parameter_dict_from_yaml_file(str(file), target_nodes=[spec.fqn]).items()}
    values = {"use_sim_time": use_sim_time} | spec.parameters
    overrides |= {k: Parameter(k, value=v) for k, v in values.items()}
    node_class = importlib.import_module(spec.module).NODE_CLASS
    return node_class(namespace=spec.namespace, parameter_overrides=list(overrides.values()), context=context)


def run_in_process(config: LaunchConfig) -> int:
    """Run every node in this process on one multi-threaded executor."""
    import rclpy  # noqa: PLC0415 - only this mode needs rclpy in the launcher itself
    from rclpy.executors import MultiThreadedExecutor  # noqa: PLC0415

    from fiper_ros.nodes.main import spin_until_shutdown  # noqa: PLC0415

    rclpy.init()
    nodes = []
    try:
        executor = MultiThreadedExecutor()
        for spec in config.nodes:
            node = build_node(spec, config.use_sim_time)
            nodes.append(node)
            executor.add_node(node)
            print(f"[launch] {spec.name} running in-process ({spec.module})", flush=True)
        spin_until_shutdown(executor)
    except KeyboardInterrupt:  # while the nodes start
        pass
    finally:
        for node in nodes:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
