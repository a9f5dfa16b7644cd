"""Launch files of ``fiper launch CONFIG.yaml`` (:mod:`fiper_ros.commands.launch`), which starts the suite's nodes as
separate OS processes (or in one, :mod:`fiper_ros.launcher.processes`).

There is no ``ros2 launch`` with the pip wheels. The config names each node's module, namespace,
parameter files and inline parameters; the launcher starts ``python -m MODULE --ros-args ...`` per
node in its own process group, prefixes their output with the node name, reports starts and exits,
forwards Ctrl-C / SIGTERM and stops everything cleanly (SIGINT, then SIGKILL after a grace period).
A node that exits is reported and the others keep running (a monitor must notice a dead peer), unless
the node is marked ``required``; a node marked ``respawn`` is started again ``respawn_delay`` seconds
after it exited (launch_ros's semantics: not while the launch stops). The launcher's exit status is 1 if
any node exited on its own. Every node process dies with the launcher (``FIPER_PARENT_PID``), even when
the launcher is killed. With ``ROS_SECURITY_ENABLE=true`` each node process runs in its own SROS2 enclave,
named as the node (docs/security.md). ``--in-process`` runs all nodes in one process on a multi-threaded
executor (one DDS participant: one enclave for all).
Before any node starts, the launcher removes the Fast DDS shared-memory files that dead processes left
(:mod:`fiper_ros.shm`) and prints how many.
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import yaml


#: ROS 2's switch for SROS2 security: when it is ``true``, every launched node runs in its own enclave.
SECURITY_ENABLE_ENV = "ROS_SECURITY_ENABLE"


class LaunchError(ValueError):
    """The launch configuration is unusable."""


@dataclass(frozen=True)
class NodeSpec:
    """One node of a launch configuration."""

    name: str
    module: str
    namespace: str
    parameter_files: tuple[Path, ...]
    parameters: dict[str, Any] = field(default_factory=dict)
    required: bool = False
    """Stop the whole launch when this node exits."""
    respawn: bool = False
    """Start the node again when it exits on its own."""
    respawn_delay: float = 0.0
    """Seconds between an exit and the respawn."""

    @property
    def fqn(self) -> str:
        """The node's fully qualified name; also its SROS2 enclave (docs/security.md)."""
        return f"{self.namespace.rstrip('/')}/{self.name}"

    def ros_args(self, use_sim_time: bool, enclave: bool = False) -> list[str]:
        """The ``--ros-args`` of this node's command line (``enclave``: with its own security enclave)."""
        args = ["--ros-args", "-r", f"__node:={self.name}", "-r", f"__ns:={self.namespace}"]
        if enclave:
            args += ["--enclave", self.fqn]
        for path in self.parameter_files:
            args += ["--params-file", str(path)]
        params = dict(self.parameters)
        params.setdefault("use_sim_time", use_sim_time)
        for key, value in params.items():
            args += ["-p", f"{key}:={yaml.safe_dump(value, default_flow_style=True).strip().removesuffix('...').strip()}"]
        return args


@dataclass(frozen=True)
class LaunchConfig:
    """A parsed launch file."""

    nodes: tuple[NodeSpec, ...]
    use_sim_time: bool

    def with_parameters(self, parameters: Callable[[NodeSpec], Mapping[str, Any]]) -> LaunchConfig:
        """This config with ``parameters(node)`` merged over each node's inline parameters."""
        return replace(self, nodes=tuple(replace(spec, parameters=spec.parameters | dict(parameters(spec)))
                                         for spec in self.nodes))


def load_config(path: Path) -> LaunchConfig:
    """Read and check a launch YAML (see fiper_ros/config/suite.yaml)."""
    if not path.is_file():
        raise LaunchError(f"launch file not found: {path}")
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data.get("nodes"), dict) or not data["nodes"]:
        raise LaunchError(f"{path}: needs a non-empty mapping 'nodes'")
    namespace = str(data.get("namespace", "/fiper"))
    files = []
    for entry in data.get("parameter_files", []):
        file = (path.parent / entry).resolve()
        if not file.is_file():
            raise LaunchError(f"{path}: parameter file not found: {file}")
        files.append(file)
    nodes = []
    for name, spec in data["nodes"].items():
        if not isinstance(spec, dict) or "module" not in spec:
            raise LaunchError(f"{path}: node {name!r} needs a 'module'")
        own = [(path.parent / f).resolve() for f in spec.get("parameter_files", [])]
        respawn_delay = float(spec.get("respawn_delay", 0.0))
        if respawn_delay < 0:
            raise LaunchError(f"{path}: node {name!r}: respawn_delay must be >= 0, got {respawn_delay}")
        nodes.append(NodeSpec(name, spec["module"], str(spec.get("namespace", namespace)), tuple(files + own),
                              dict(spec.get("parameters", {})), bool(spec.get("required", False)),
                              bool(spec.get("respawn", False)), respawn_delay))
    return LaunchConfig(tuple(nodes), bool(data.get("use_sim_time", False)))


def dump_config(config: LaunchConfig, path: Path) -> Path:
    """Write ``config`` as a launch YAML that :func:`load_config` reads back unchanged (absolute paths)."""
    nodes = {spec.name: {"module": spec.module, "namespace": spec.namespace, "required": spec.required,
                         "respawn": spec.respawn, "respawn_delay": spec.respawn_delay,
                         "parameter_files": [str(p) for p in spec.parameter_files],
                         "parameters": dict(spec.parameters)} for spec in config.nodes}
    path.write_text(yaml.safe_dump({"use_sim_time": config.use_sim_time, "nodes": nodes}, sort_keys=False))
    return path
