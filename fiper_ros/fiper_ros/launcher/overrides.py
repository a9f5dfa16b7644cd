"""The one way a tool adapts a launch configuration before it starts the suite: which nodes run, their
parameters, sim time (``fiper replay``, ``fiper demo``, ``fiper collect --ros``).

A tool never edits a launch YAML by hand: it reads it with the launcher's own parser
(:func:`~fiper_ros.launcher.config.load_config`), applies :class:`Overrides` and writes it again, so the
nodes are exactly those of a normal launch. Parameters are chosen per node by its module (every node that
runs it), by its name, or only where the file already sets them (paths made absolute); they are merged over
the node's inline parameters.
"""
from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fiper_ros.launcher.config import LaunchConfig, NodeSpec, dump_config, load_config


@dataclass(frozen=True)
class Overrides:
    """What to change in a launch configuration.

    Attributes:
        by_module: Node module -> parameters for every node that runs it.
        by_name: Node name -> parameters.
        where_set: Parameters set only on the nodes whose inline parameters already hold them.
        keep: Names of the nodes to run (None: all); the others are dropped.
        required: Mark every node that runs as ``required`` (the launch stops when one exits).
        use_sim_time: Sim time for the whole launch (None: as in the file).
    """

    by_module: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    by_name: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    where_set: Mapping[str, Any] = field(default_factory=dict)
    keep: tuple[str, ...] | None = None
    required: bool = False
    use_sim_time: bool | None = None

    def parameters(self, spec: NodeSpec) -> dict[str, Any]:
        """The parameters these overrides set on the node ``spec``."""
        return (dict(self.by_module.get(spec.module, {})) | dict(self.by_name.get(spec.name, {}))
                | {key: value for key, value in self.where_set.items() if key in spec.parameters})


def apply(config: LaunchConfig, overrides: Overrides) -> LaunchConfig:
    """``config`` with ``overrides`` applied."""
    nodes = config.nodes if overrides.keep is None else tuple(s for s in config.nodes if s.name in overrides.keep)
    if overrides.required:
        nodes = tuple(replace(spec, required=True) for spec in nodes)
    config = replace(config, nodes=nodes).with_parameters(overrides.parameters)
    return config if overrides.use_sim_time is None else replace(config, use_sim_time=overrides.use_sim_time)


def rewrite(source: Path, overrides: Overrides, out: Path) -> Path:
    """Read the launch YAML ``source``, apply ``overrides``, write the result to ``out`` (returned).
    :class:`~fiper_ros.launcher.config.LaunchError` or ``yaml.YAMLError`` for an unusable ``source``."""
    return dump_config(apply(load_config(source), overrides), out)
