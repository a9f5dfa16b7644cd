"""One home per parameter default (#20): the node's own declaration (``declare_parameter``, with its description
and range). A shipped launch file or parameter file sets a parameter only to choose another value for that launch;
it never restates a default, and a launch argument that passes a value through to a node (``combine:=``,
``use_sim_time:=``, ``batch:=``, ...) has that node's default as its own default. So no file can drift from the
code: a repeated default, or one repeated with a different value, fails here."""
from __future__ import annotations

import importlib
import itertools
import os
import re
import shlex
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import rclpy
import yaml
from rclpy.context import Context
from rclpy.exceptions import ParameterUninitializedException
from rclpy.parameter import Parameter

from fiper_ros.launcher.config import load_launch, node_module
from fiper_ros.nodes import container

ROOT = Path(os.environ["FIPER_ROOT"])
LAUNCH_FILES = sorted([*(ROOT / "fiper_ros" / "launch").glob("*.launch.yaml"),
                       *(ROOT / "sim_bridge" / "launch").glob("*.launch.yaml")])
PARAMETER_FILES = [ROOT / "fiper_ros" / "config" / "nodes.yaml"]
#: Launch arguments that choose a deployment's value (a path, a namespace), not a node default passed through.
DEPLOYMENT_ARGUMENTS = {"calibration_dir", "model", "params_file", "namespace"}


class Defaults:
    """Each node module's declared defaults, from a node built (never spun) in a context of the test's own."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.nodes: dict[str, Any] = {}

    def of(self, module: str, name: str) -> tuple[bool, Any]:
        """Whether the node of ``module`` declares ``name``, and its default."""
        if module not in self.nodes:
            self.nodes[module] = importlib.import_module(module).NODE_CLASS(context=self.context, namespace="/test")
        node = self.nodes[module]
        if not node.has_parameter(name):
            return False, None
        try:
            value = node.get_parameter(name).value
        except ParameterUninitializedException:  # declared with a type and no default ("unset")
            return True, None
        return True, value.tolist() if hasattr(value, "tolist") else list(value) if isinstance(value, tuple) else value

    def close(self) -> None:
        for node in self.nodes.values():
            node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def defaults(ros_domain: int) -> Iterator[Defaults]:
    made = Defaults(ros_domain)
    try:
        yield made
    finally:
        made.close()


def same(value: Any, default: Any) -> bool:
    """Equal in value and type (``1`` is not ``1.0``: ROS would refuse the type)."""
    return type(value) is type(default) and value == default


def launch_problems(path: Path, defaults: Defaults) -> list[str]:
    """What the launch file ``path`` (read as written: its own ``arg`` defaults and ``let`` values) does against the
    one-home rule."""
    entries = yaml.safe_load(path.read_text())["launch"]
    arguments = {e["arg"]["name"]: e["arg"].get("default") for e in entries if "arg" in e}
    problems = []
    for entry in entries:
        if "node" not in entry:
            continue
        node = entry["node"]
        module = node_module(node["pkg"], node["exec"])
        # a container's parameters reach each of its nodes, and each takes those it declares
        modules = container.node_modules(shlex.split(node["args"])) if module == container.__name__ else [module]
        for param in node.get("param", []):
            if "from" in param:
                continue
            name, value = param["name"], param["value"]
            where = f"{path.name}: {node.get('name', node['exec'])}: {name}"
            declaring = [(m, default) for m in modules for declared, default in [defaults.of(m, name)] if declared]
            if not declaring:
                problems.append(f"{where}: not a parameter of {' or '.join(modules)}")
            for _, default in declaring:
                if isinstance(value, str) and value.startswith("$(var ") and value.endswith(")"):
                    argument = value[len("$(var "):-1]
                    if argument in arguments and argument not in DEPLOYMENT_ARGUMENTS:
                        passed = yaml.safe_load(str(arguments[argument]))
                        if not same(passed, default):
                            problems.append(f"{where}: argument {argument}'s default {passed!r} is not the node's "
                                            f"default {default!r}")
                elif "$(" not in str(value) and same(yaml.safe_load(value) if isinstance(value, str) else value,
                                                     default):
                    problems.append(f"{where}: repeats the node's default {default!r}")
    return problems


def parameter_file_problems(path: Path, modules: dict[str, str], defaults: Defaults) -> list[str]:
    """A parameter file's entries against the declarations of the nodes they apply to (``modules``: fully
    qualified name -> module, of every node the shipped launch files start)."""
    problems = []
    for key, entry in (yaml.safe_load(path.read_text()) or {}).items():
        targets = modules if key == "/**" else {key: modules[key]} if key in modules else {}
        if not targets:
            problems.append(f"{path.name}: {key}: no shipped launch file starts this node")
        for name, value in entry["ros__parameters"].items():
            for fqn, module in targets.items():
                declared, default = defaults.of(module, name)
                if not declared:
                    problems.append(f"{path.name}: {fqn}: {name}: not a parameter of {module}")
                elif same(value, default):
                    problems.append(f"{path.name}: {fqn}: {name}: repeats the node's default {default!r}")
    return problems


def test_no_shipped_launch_or_parameter_file_repeats_a_default(defaults: Defaults) -> None:
    problems = [problem for path in LAUNCH_FILES for problem in launch_problems(path, defaults)]
    modules = {spec.fqn: spec.module for path in LAUNCH_FILES for spec in load_launch(path).nodes}
    problems += [problem for path in PARAMETER_FILES for problem in parameter_file_problems(path, modules, defaults)]
    assert problems == []
    assert len(LAUNCH_FILES) == 4 and {"/fiper/fusion_node", "/sim/bridge_node"} <= set(modules)


def test_every_value_a_shipped_launch_file_gives_has_the_declared_type(defaults: Defaults) -> None:
    for path in LAUNCH_FILES:
        for spec in load_launch(path).nodes:
            for name, value in spec.parameters.items():
                declared, default = defaults.of(spec.module, name)
                assert declared, (path.name, spec.name, name)
                assert type(value) is type(default), (path.name, spec.name, name, value, default)


def test_a_repeated_default_and_a_pass_through_with_another_default_are_caught(tmp_path: Path,
                                                                               defaults: Defaults) -> None:
    bad = tmp_path / "bad.launch.yaml"
    bad.write_text(yaml.safe_dump({"launch": [
        {"arg": {"name": "combine", "default": "or"}},
        {"arg": {"name": "deadline", "default": "1"}},
        {"node": {"pkg": "fiper_ros", "exec": "fusion_node", "name": "fusion_node", "param": [
            {"name": "heartbeat_s", "value": 0.5}, {"name": "combine", "value": "$(var combine)"},
            {"name": "deadline_s", "value": "$(var deadline)"}, {"name": "buffer_size", "value": 32},
            {"name": "no_such_parameter", "value": 1}]}}]}))
    assert launch_problems(bad, defaults) == [
        "bad.launch.yaml: fusion_node: heartbeat_s: repeats the node's default 0.5",
        "bad.launch.yaml: fusion_node: combine: argument combine's default 'or' is not the node's default 'calibration'",
        "bad.launch.yaml: fusion_node: deadline_s: argument deadline's default 1 is not the node's default 1.0",
        "bad.launch.yaml: fusion_node: no_such_parameter: not a parameter of fiper_ros.nodes.fusion_node"]
    params = tmp_path / "nodes.yaml"
    params.write_text(yaml.safe_dump({"/**": {"ros__parameters": {"diagnostics_period_s": 1.0}},
                                      "/fiper/fusion_node": {"ros__parameters": {"combine": "or"}},
                                      "/elsewhere/node": {"ros__parameters": {"x": 1}}}))
    modules = {"/fiper/fusion_node": "fiper_ros.nodes.fusion_node"}
    assert parameter_file_problems(params, modules, defaults) == [
        "nodes.yaml: /fiper/fusion_node: diagnostics_period_s: repeats the node's default 1.0",
        "nodes.yaml: /elsewhere/node: no shipped launch file starts this node"]


#: The parameter tables of the docs (file, a line of the text just before the table) and the node modules a row
#: without a ``node`` column is about.
DOC_TABLES = [(ROOT / "docs" / "nodes.md", "Who may publish what a node consumes", ()),
              (ROOT / "docs" / "nodes.md", "Parameters (all read-only; the defaults are the node's declarations",
               ("fiper_ros.nodes.policy_node",)),
              (ROOT / "docs" / "sim.md", "All read-only (set them at start-up); the defaults are the node's",
               ("sim_bridge.bridge_node",))]
#: The ``node`` column's words.
DOC_NODES = {"scoring nodes": ("fiper_ros.nodes.rnd_oe_node", "fiper_ros.nodes.ace_node"),
             "fusion": ("fiper_ros.nodes.fusion_node",), "supervisor": ("fiper_ros.nodes.supervisor_node",)}
#: Default cells in words, and what each says of the declared default (None: said elsewhere in the docs, the
#: ``FiperNode`` shell's or the topic table's).
DOC_WORDS = {"unset": lambda default: default in ("", [], None), "as the suite": None,
             "as the bridge publishes them": None, "as in the topic table": None}


def doc_table(path: Path, before: str) -> list[dict[str, str]]:
    """The rows of the first markdown table after the line holding ``before``, as header -> cell."""
    lines = path.read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if before in line)
    table = [line for line in itertools.takewhile(lambda line: line.startswith("|"),
                                                  itertools.dropwhile(lambda line: not line.startswith("|"),
                                                                      lines[start:]))]
    cells = [[cell.strip() for cell in line.strip("|").split(" | ")] for line in table]
    return [dict(zip(cells[0], row)) for row in cells[2:]]


def doc_problems(path: Path, before: str, modules: tuple[str, ...], defaults: Defaults) -> list[str]:
    """A docs parameter table against the declarations: every name a parameter of its node(s), every default
    cell the declared default (one value for all the row's names, or one per name) or words of :data:`DOC_WORDS`."""
    problems = []
    for row in doc_table(path, before):
        names = re.findall(r"`([^`]+)`", row["parameter"])
        nodes = [module for word in row["node"].split(", ") for module in DOC_NODES[word]] if "node" in row \
            else list(modules)
        cell = row["default"]
        values: list[Any] = [yaml.safe_load(value.strip("`")) for value in re.split(r",\s*(?![^\[]*\])", cell)]
        for index, name in enumerate(names):
            for module in nodes:
                declared, default = defaults.of(module, name)
                where = f"{path.name}: {name} ({module})"
                if not declared:
                    problems.append(f"{where}: not a parameter")
                elif cell in DOC_WORDS:
                    check = DOC_WORDS[cell]
                    if check is not None and not check(default):
                        problems.append(f"{where}: says {cell!r}, the default is {default!r}")
                elif len(values) not in (1, len(names)):
                    problems.append(f"{where}: {len(values)} defaults for {len(names)} parameters")
                elif not same(values[index if len(values) > 1 else 0], default):
                    problems.append(f"{where}: says {cell}, the default is {default!r}")
    return problems


def test_the_docs_parameter_tables_state_the_declared_defaults(defaults: Defaults) -> None:
    problems = [problem for path, before, modules in DOC_TABLES
                for problem in doc_problems(path, before, modules, defaults)]
    assert problems == []
    assert sum(len(doc_table(path, before)) for path, before, _ in DOC_TABLES) >= 20  # the tables were found


def test_a_docs_table_with_a_wrong_default_is_caught(tmp_path: Path, defaults: Defaults) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("The table:\n\n| parameter | node | default | meaning |\n| --- | --- | --- | --- |\n"
                   "| `allow_reset` | fusion | `false` | x |\n| `deadline_s`, `buffer_size` | fusion | 1.0, 64 | x |\n"
                   "| `allowed_publishers` | scoring nodes | unset | x |\n| `no_such` | supervisor | 1 | x |\n")
    assert doc_problems(doc, "The table:", (), defaults) == [
        "doc.md: allow_reset (fiper_ros.nodes.fusion_node): says `false`, the default is True",
        "doc.md: no_such (fiper_ros.nodes.supervisor_node): not a parameter"]


#: Parameters rclpy itself applies when they are set.
APPLIED_BY_RCLPY = {"use_sim_time"}


def test_no_parameter_accepts_a_set_that_nothing_applies(defaults: Defaults) -> None:
    """No node applies a parameter set at run time, so each is read-only: ``ros2 param set`` is refused with a
    reason, never accepted and ignored (``use_sim_time`` aside: rclpy applies it)."""
    modules = sorted({spec.module for path in LAUNCH_FILES for spec in load_launch(path).nodes
                      if spec.module != container.__name__} | {"fiper_ros.nodes.detector_node"})
    assert {"fiper_ros.nodes.fusion_node", "fiper_ros.nodes.detector_node", "sim_bridge.bridge_node"} <= set(modules)
    for module in modules:
        defaults.of(module, "use_sim_time")  # builds the node
        node = defaults.nodes[module]
        names = [n for n in node.list_parameters([], 0).names
                 if n not in APPLIED_BY_RCLPY and not n.startswith("qos_overrides.")]
        assert names, module
        writable = [n for n, d in zip(names, node.describe_parameters(names)) if not d.read_only]
        assert writable == [], (module, writable)
        name = names[0]
        (result,) = node.set_parameters([Parameter(name, value=node.get_parameter(name).value)])
        assert not result.successful and "read-only" in result.reason, (module, name, result.reason)
