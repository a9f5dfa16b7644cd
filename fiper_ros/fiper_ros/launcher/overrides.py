"""The one way a tool adapts a launch file beyond its launch arguments before it starts the suite: which nodes
run, which are required, and parameters the file has no argument for (``fiper collect --ros``, ``fiper replay``
with a robot model, the benchmarks).

A tool never edits a launch YAML by hand: it reads it with the launcher's own reader
(:func:`~fiper_ros.launcher.config.load_launch`, with the launch arguments it sets, such as ``calibration_dir``),
applies :class:`Overrides` and writes the result as a launch file of literal values
(:func:`~fiper_ros.launcher.config.dump_launch`), so the nodes are exactly those of a normal launch. Parameters
are chosen per node by its module (every node that runs it) or by its name; they are set after the node's own,
so they win.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fiper_ros.launcher.config import LaunchConfig, NodeSpec, dump_launch, load_launch


@dataclass(frozen=True)
class Overrides:
    """What to change in a launch configuration.

    Attributes:
        by_module: Node module -> parameters for every node that runs it.
        by_name: Node name -> parameters.
        keep: Names of the nodes to run (None: all); the others are dropped.
        required: Mark every node that runs as ``required`` (the launch stops when one exits).
    """

    by_module: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    by_name: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    keep: tuple[str, ...] | None = None
    required: bool = False

    def parameters(self, spec: NodeSpec) -> dict[str, Any]:
        """The parameters these overrides set on the node ``spec``."""
        return dict(self.by_module.get(spec.module, {})) | dict(self.by_name.get(spec.name, {}))


def apply(config: LaunchConfig, overrides: Overrides) -> LaunchConfig:
    """``config`` with ``overrides`` applied."""
    nodes = config.nodes if overrides.keep is None else tuple(s for s in config.nodes if s.name in overrides.keep)
    if overrides.required:
        nodes = tuple(replace(spec, required=True) for spec in nodes)
    return replace(config, nodes=nodes).with_parameters(overrides.parameters)


def rewrite(source: Path, overrides: Overrides, out: Path, arguments: Mapping[str, str] | None = None) -> Path:
    """Read the launch file ``source`` with the launch ``arguments``, apply ``overrides``, write the result to
    ``out`` (returned). :class:`~fiper_ros.launcher.config.LaunchError` for an unusable ``source``."""
    return dump_launch(apply(load_launch(source, arguments), overrides), out)
