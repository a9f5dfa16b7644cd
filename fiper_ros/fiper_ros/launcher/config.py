"""Launch files: the ROS 2 launch-YAML schema, the part of it ``fiper launch`` reads, so that one file serves
``ros2 launch`` on a full ROS install and ``fiper launch`` here (where the pip wheels have no ``launch_ros``).

A launch file is ``launch:``, a list of tags (docs/install.md, "Launch files", has the table):

- ``arg`` (``name``, ``default``, ``description``, ``choice: [{value: ...}]``): a launch argument, given on the
  command line as ``name:=value``; without a default it must be given.
- ``let`` (``name``, ``value``): a launch configuration set in the file.
- ``include`` (``file``, ``arg: [{name, value}]``): another launch file, read in the same scope (as
  ``IncludeLaunchDescription`` does): its arguments see the values set here and on the command line.
- ``node`` (``pkg``, ``exec``, ``name``, ``namespace``, ``param``, ``remap``, ``respawn``, ``respawn_delay``,
  ``respawn_max_retries``, ``output`` (``screen``, ``log``, ``both``), ``args``, ``ros_args``,
  ``on_exit: shutdown``): one node process. ``pkg`` + ``exec`` name a console
  script of an installed ament_python package (what ``ros2 run`` starts); the launcher runs its module, with
  ``args`` (split as a shell does) before its ``--ros-args``. ``name`` renames the process's node; an entry
  without one leaves the names to the process (a ``container`` of several nodes, :mod:`fiper_ros.nodes.container`)
  and is known to the launcher by its ``exec``, its name/value parameters keyed ``/**`` (every node of it).
  ``param`` entries are ``{from: FILE}`` or ``{name, value}`` (nested ``param`` lists give dotted names),
  applied in order, later ones winning, as ``launch_ros`` does; a value's text is read as YAML after its
  substitutions, so ``'true'`` is a bool and ``"'1.0'"`` a string. ``on_exit: shutdown`` makes the node
  *required*: when it exits, the launch stops.

Substitutions: :mod:`fiper_ros.launcher.substitutions`. A file path (``from``, ``include``) must be absolute once
substituted (``$(find-pkg-share PKG)/...`` or ``$(dirname)/...``): a launch file means the same from any working
directory. Anything else (another tag, attribute or substitution) is refused with one line naming it.

The launcher itself (:mod:`fiper_ros.launcher.processes`) starts each node as ``python -m MODULE --ros-args ...``
in its own process group, relays its output prefixed with the node name (``output: screen``, the default), into
its log file (``log``: :func:`fiper_ros.launcher.processes.launch_log_directory` says where) or both, respawns a
``respawn`` node ``respawn_delay`` seconds after it exited (not while the launch stops; at most
``respawn_max_retries`` times, -1: unlimited, as ``launch_ros``), stops everything when a required node
exits, forwards Ctrl-C / SIGTERM (SIGINT, then SIGKILL after a grace period) and exits 1 if any node exited on its
own. Every node process dies with the launcher (``FIPER_PARENT_PID``). With ``ROS_SECURITY_ENABLE=true`` each
node process runs in its own SROS2 enclave, named as the node (docs/security.md). ``--in-process`` runs all
nodes in one process on a multi-threaded executor (one DDS participant: one enclave for all). Before any node
starts, the launcher removes the Fast DDS shared-memory files that dead processes left (:mod:`fiper_ros.platform.shm`).
"""
from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from importlib.metadata import PackageNotFoundError, distribution
from pathlib import Path
from typing import Any, Union

import yaml

from fiper_ros.launcher.errors import LaunchError
from fiper_ros.launcher.substitutions import Context, SubstitutionError, has_substitution, substitute
from fiper_ros.runtime.trusted_publishers import fully_qualified

#: ROS 2's switch for SROS2 security: when it is ``true``, every launched node runs in its own enclave.
SECURITY_ENABLE_ENV = "ROS_SECURITY_ENABLE"
#: Tag -> the attributes ``fiper launch`` reads (every other one is refused).
TAGS: dict[str, frozenset[str]] = {
    "arg": frozenset({"name", "default", "description", "choice"}),
    "let": frozenset({"name", "value"}),
    "include": frozenset({"file", "arg"}),
    "node": frozenset({"pkg", "exec", "name", "namespace", "param", "remap", "respawn", "respawn_delay",
                       "respawn_max_retries", "output", "args", "ros_args", "on_exit"}),
}
#: A node's ``output``, as ``launch_ros``: its lines on the launcher's screen, in its log file, or in both.
OUTPUTS = ("screen", "log", "both")
#: ``respawn_max_retries`` of a node that does not set it: respawned without limit (``launch_ros``'s -1).
UNLIMITED_RESPAWNS = -1
#: Attributes every tag takes: ``if: $(var x)`` / ``unless: ...`` (``true``/``false``/``1``/``0``) skip the tag.
CONDITIONS = frozenset({"if", "unless"})
#: Includes nested deeper than this are refused (a file that includes itself).
MAX_INCLUDE_DEPTH = 8
#: Types a parameter value may have (``launch_ros``: a scalar or a non-empty list of one of them).
SCALARS = (bool, int, float, str)

ParameterEntry = Union[Path, Mapping[str, Any]]
"""One ``param`` entry of a node: a parameter file, or parameters by name."""


@dataclass(frozen=True)
class NodeSpec:
    """One node of a launch file, every substitution evaluated."""

    name: str
    """The node's name; for an entry without one (:attr:`named` false), its executable: the launcher's name of the
    process (its output's prefix, its log file, its respawns)."""
    package: str
    executable: str
    module: str
    """The executable's Python module (run as ``python -m``)."""
    namespace: str
    params: tuple[ParameterEntry, ...] = ()
    """The ``param`` entries in order: files and name/value mappings; a later one wins."""
    remaps: tuple[tuple[str, str], ...] = ()
    ros_arguments: tuple[str, ...] = ()
    """The ``ros_args`` tokens (e.g. ``--log-level info``)."""
    required: bool = False
    """``on_exit: shutdown``: stop the whole launch when this node exits."""
    respawn: bool = False
    """Start the node again when it exits on its own."""
    respawn_delay: float = 0.0
    """Seconds between an exit and the respawn."""
    respawn_max_retries: int = UNLIMITED_RESPAWNS
    """Respawns at most (:data:`UNLIMITED_RESPAWNS`: no limit); after them an exit is final."""
    output: str = "screen"
    """Where the node's output goes (one of :data:`OUTPUTS`)."""
    arguments: tuple[str, ...] = ()
    """The ``args`` tokens: the process's own arguments, before ``--ros-args``."""
    named: bool = True
    """Whether the entry names the node (``-r __node:=NAME``); else the process names its nodes."""

    @property
    def to_screen(self) -> bool:
        """Whether the launcher relays the node's lines to its own output."""
        return self.output in ("screen", "both")

    @property
    def to_log(self) -> bool:
        """Whether the node's lines go to its log file."""
        return self.output in ("log", "both")

    def may_respawn(self, respawns: int) -> bool:
        """Whether the node is started again after an exit, having been respawned ``respawns`` times."""
        return self.respawn and (self.respawn_max_retries == UNLIMITED_RESPAWNS or respawns < self.respawn_max_retries)

    @property
    def fqn(self) -> str:
        """The node's fully qualified name (for an entry without a name: its executable's under its namespace)."""
        return fully_qualified(self.namespace, self.name)

    @property
    def enclave(self) -> str:
        """The node process's SROS2 enclave: the node's fully qualified name (docs/security.md). An entry without a
        name has none (:class:`LaunchError`): an enclave grants one node's topics and services."""
        if not self.named:
            raise LaunchError(f"node entry {self.executable!r} without a name: under ROS_SECURITY_ENABLE=true each "
                              "process runs in the enclave of its one node (docs/security.md); launch its nodes as "
                              "processes of their own (fiper.launch.yaml compose:=false)")
        return self.fqn

    @property
    def parameter_files(self) -> tuple[Path, ...]:
        """The parameter files among :attr:`params`, in order."""
        return tuple(entry for entry in self.params if isinstance(entry, Path))

    @property
    def parameters(self) -> dict[str, Any]:
        """The parameters set by name, merged in order (a later entry wins)."""
        merged: dict[str, Any] = {}
        for entry in self.params:
            if not isinstance(entry, Path):
                merged.update(entry)
        return merged

    def with_parameters(self, values: Mapping[str, Any]) -> NodeSpec:
        """This node with ``values`` set after its own parameters (so they win; merged into a last name/value
        entry, as reading a file merges neighbouring ones)."""
        if not values:
            return self
        if self.params and not isinstance(self.params[-1], Path):
            return replace(self, params=(*self.params[:-1], {**self.params[-1], **values}))
        return replace(self, params=(*self.params, dict(values)))

    @property
    def parameter_key(self) -> str:
        """The node key of the parameter file a name/value entry becomes: the node's name, or ``/**`` (every node
        of the process) for an entry without one, as ``launch_ros``."""
        return self.fqn if self.named else "/**"

    def ros_args(self, params_dir: Path, enclave: bool = False) -> list[str]:
        """The ``--ros-args`` of this node's command line (``enclave``: with its own security enclave). As
        ``launch_ros`` does, each name/value entry becomes a parameter file keyed by :attr:`parameter_key` (written
        into ``params_dir``), so that every entry is a ``--params-file`` in order and a later one
        wins: rcl ranks ``-p`` rules by their own rules, not by their place on the command line."""
        args = ["--ros-args", *(("-r", f"__node:={self.name}") if self.named else ()), "-r", f"__ns:={self.namespace}"]
        if enclave:
            args += ["--enclave", self.enclave]
        for index, entry in enumerate(self.params):
            if not isinstance(entry, Path):
                path = params_dir / f"{self.name}.{index}.yaml"
                path.write_text(yaml.safe_dump({self.parameter_key: {"ros__parameters": dict(entry)}}))
                entry = path
            args += ["--params-file", str(entry)]
        for source, target in self.remaps:
            args += ["-r", f"{source}:={target}"]
        return args + list(self.ros_arguments)

    def command(self, params_dir: Path, enclave: bool = False) -> list[str]:
        """The node process's command line (its name/value parameters written into ``params_dir``)."""
        return [sys.executable, "-m", self.module, *self.arguments, *self.ros_args(params_dir, enclave)]


@dataclass(frozen=True)
class Argument:
    """A declared launch argument."""

    name: str
    default: str | None
    """The default as written (substitutions unevaluated); None: the argument must be given."""
    description: str = ""
    choices: tuple[str, ...] = ()


@dataclass(frozen=True)
class LaunchConfig:
    """A read launch file: its nodes, the arguments it (and what it includes) declares, and their values."""

    nodes: tuple[NodeSpec, ...]
    arguments: tuple[Argument, ...] = ()
    values: Mapping[str, str] = field(default_factory=dict)
    """Every launch configuration at the end of the file (arguments and ``let``), evaluated."""

    def with_parameters(self, parameters: Callable[[NodeSpec], Mapping[str, Any]]) -> LaunchConfig:
        """This config with ``parameters(node)`` set on each node after its own."""
        return replace(self, nodes=tuple(spec.with_parameters(parameters(spec)) for spec in self.nodes))


def parse_arguments(items: Sequence[str]) -> dict[str, str]:
    """``["name:=value", ...]`` (the command line's launch arguments) as a mapping."""
    arguments: dict[str, str] = {}
    for item in items:
        name, sep, value = item.partition(":=")
        if not sep or not name:
            raise LaunchError(f"launch arguments are name:=value, got {item!r}")
        arguments[name] = value
    return arguments


def load_launch(path: Path, arguments: Mapping[str, str] | None = None,
                env: Mapping[str, str] | None = None) -> LaunchConfig:
    """Read the launch file ``path`` with the launch ``arguments`` (name -> value) given; :class:`LaunchError`
    for anything it cannot run, and for an argument it does not declare."""
    given = dict(arguments or {})
    reader = _Reader(given, os.environ if env is None else env)
    reader.read(Path(path), 0)
    declared = {argument.name for argument in reader.declared}
    unknown = sorted(set(given) - declared)
    if unknown:
        raise LaunchError(f"{path}: unknown launch argument{'s' if len(unknown) > 1 else ''} {', '.join(unknown)} "
                          f"(it declares: {', '.join(sorted(declared)) or 'none'})")
    first: dict[str, Argument] = {}
    for argument in reader.declared:  # an included file may declare an argument again
        first.setdefault(argument.name, argument)
    return LaunchConfig(tuple(reader.nodes), tuple(first.values()), dict(reader.variables))


def dump_launch(config: LaunchConfig, path: Path) -> Path:
    """Write ``config``'s nodes as a launch file (no arguments, every value literal and every path absolute)
    that :func:`load_launch` reads back into the same nodes; ``ros2 launch`` runs it too."""
    entries = []
    for spec in config.nodes:
        node: dict[str, Any] = {"pkg": spec.package, "exec": spec.executable,
                                **({"name": spec.name} if spec.named else {}),
                                "namespace": spec.namespace, "output": spec.output}
        if spec.arguments:
            node["args"] = shlex.join(spec.arguments)
        params = []
        for entry in spec.params:
            if isinstance(entry, Path):
                params.append({"from": str(entry)})
            else:
                params += [{"name": key, "value": _literal(value, f"{spec.name}: parameter {key}")}
                           for key, value in entry.items()]
        if params:
            node["param"] = params
        if spec.remaps:
            node["remap"] = [{"from": source, "to": target} for source, target in spec.remaps]
        if spec.ros_arguments:
            node["ros_args"] = shlex.join(spec.ros_arguments)
        if spec.respawn:
            node |= {"respawn": "true", "respawn_delay": spec.respawn_delay}
            if spec.respawn_max_retries != UNLIMITED_RESPAWNS:
                node["respawn_max_retries"] = spec.respawn_max_retries
        if spec.required:
            node["on_exit"] = "shutdown"
        entries.append({"node": node})
    path.write_text(yaml.safe_dump({"launch": entries}, sort_keys=False))
    return path


def package_share(name: str) -> str:
    """``$(find-pkg-share name)``: the package's share directory on the ament index."""
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory  # noqa: PLC0415

    try:
        return get_package_share_directory(name)
    except PackageNotFoundError:
        raise SubstitutionError(f"$(find-pkg-share {name}): no package {name!r} on the ament index "
                                "(AMENT_PREFIX_PATH; source env.sh or the workspace's setup)") from None


@lru_cache(maxsize=None)
def _console_scripts(package: str) -> dict[str, str]:
    """``package``'s console scripts (its installed distribution's): name -> ``module:function``; empty if it is
    not installed. One distribution's metadata is read, not every installed one's (that took 0.12 s of the
    launcher's start-up)."""
    try:
        points = distribution(package).entry_points
    except PackageNotFoundError:
        return {}
    return {point.name: point.value for point in points if point.group == "console_scripts"}


def node_module(package: str, executable: str) -> str:
    """The Python module of ``package``'s executable ``executable`` (its console script ``MODULE:main``)."""
    scripts = _console_scripts(package)
    if not scripts:
        raise LaunchError(f"package {package!r} has no Python executables installed (fiper launch runs the "
                          "console scripts of ament_python packages)")
    if executable not in scripts:
        raise LaunchError(f"package {package!r} has no executable {executable!r} (it has {', '.join(sorted(scripts))})")
    module, _, function = scripts[executable].partition(":")
    if function.strip() != "main":
        raise LaunchError(f"{package}/{executable} is {scripts[executable]}: fiper launch runs an executable's "
                          "module (python -m), so its entry point must be MODULE:main")
    return module.strip()


def _text(raw: Any) -> str:
    """A scalar attribute as the text a launch file means by it (YAML's ``true`` is ``'true'``)."""
    return str(raw).lower() if isinstance(raw, bool) else str(raw)


def _flow(value: Any) -> str:
    """``value`` as YAML flow text (a string that reads as another type is quoted)."""
    return yaml.safe_dump(value, default_flow_style=True).strip().removesuffix("...").strip()


def _literal(value: Any, where: str) -> Any:
    """``value`` as a launch file writes it so that reading gives ``value`` back (strings that read as another
    type quoted, as ``launch_ros`` wants)."""
    if isinstance(value, (list, tuple)):
        return [_literal(item, where) for item in value]
    if isinstance(value, str):
        if "$(" in value:
            raise LaunchError(f"{where}: {value!r} would read as a substitution")
        return value if value and yaml.safe_load(value) == value else _flow(value)
    return value


class _Reader:
    """Walks a launch file (and what it includes) in one scope of launch configurations."""

    def __init__(self, given: dict[str, str], env: Mapping[str, str]) -> None:
        self.variables: dict[str, str] = dict(given)
        self.env = env
        self.declared: list[Argument] = []
        self.nodes: list[NodeSpec] = []

    def read(self, path: Path, depth: int) -> None:
        if depth > MAX_INCLUDE_DEPTH:
            raise LaunchError(f"{path}: includes nested deeper than {MAX_INCLUDE_DEPTH} (a file that includes itself?)")
        if not path.is_file():
            raise LaunchError(f"launch file not found: {path}")
        try:
            data = yaml.safe_load(path.read_text())
        except yaml.YAMLError as error:
            raise LaunchError(f"{path}: not YAML: {' '.join(str(error).split())}") from None
        if not isinstance(data, dict) or not isinstance(data.get("launch"), list) or set(data) != {"launch"}:
            hint = " (fiper's own format with 'nodes:' is gone: see fiper_ros/launch/)" if isinstance(data, dict) \
                and "nodes" in data else ""
            raise LaunchError(f"{path}: not a ROS 2 launch YAML: expected one top-level list 'launch:'{hint}")
        context = Context(self.variables, self.env, package_share, str(path.parent.resolve()))
        for index, item in enumerate(data["launch"]):
            if not isinstance(item, dict) or len(item) != 1:
                raise LaunchError(f"{path}: launch entry {index + 1} must be one tag (arg, let, include, node)")
            ((tag, attributes),) = item.items()
            if tag not in TAGS:
                raise LaunchError(f"{path}: tag {tag!r} is not supported by fiper launch "
                                  f"(it reads {', '.join(TAGS)})")
            entry = _Entry(path, tag, attributes or {}, context)
            try:
                if entry.applies():
                    getattr(self, f"_{tag}")(entry, depth)
            except SubstitutionError as error:
                raise LaunchError(f"{entry.where}: {error}") from None

    def _arg(self, entry: _Entry, depth: int) -> None:
        name = entry.text("name", literal=True)
        default = entry.optional("default")
        choices = tuple(_text(choice.get("value", "")) for choice in entry.mappings("choice", {"value"}, {"value"}))
        self.declared.append(Argument(name, None if default is None else _text(default),
                                      str(entry.optional("description") or ""), choices))
        if name not in self.variables:
            if default is None:
                raise LaunchError(f"{entry.path}: launch argument {name!r} has no default: give {name}:=VALUE")
            self.variables[name] = substitute(_text(default), entry.context)
        if choices and self.variables[name] not in choices:
            raise LaunchError(f"{entry.path}: launch argument {name}:={self.variables[name]!r} is not one of "
                              f"{', '.join(choices)}")

    def _let(self, entry: _Entry, depth: int) -> None:
        self.variables[entry.text("name", literal=True)] = entry.text("value")

    def _include(self, entry: _Entry, depth: int) -> None:
        file = entry.path_of(entry.text("file"), "file")
        for argument in entry.mappings("arg", {"name", "value"}, {"name", "value"}):
            self.variables[_text(argument["name"])] = substitute(_text(argument["value"]), entry.context)
        self.read(file, depth + 1)

    def _node(self, entry: _Entry, depth: int) -> None:
        package, executable = entry.text("pkg"), entry.text("exec")
        given = entry.text("name", default="")
        name = given or executable
        entry.where = f"{entry.path}: node {name!r}"
        if any(spec.name == name for spec in self.nodes):
            raise LaunchError(f"{entry.where}: a second node of this name (fiper launch names processes by node)")
        namespace = "/" + entry.text("namespace", default="/").strip("/")
        output = entry.text("output", default="screen")
        if output not in OUTPUTS:
            raise LaunchError(f"{entry.where}: output {output!r} is not supported (one of {', '.join(OUTPUTS)})")
        on_exit = entry.text("on_exit", default="")
        if on_exit not in ("", "shutdown"):
            raise LaunchError(f"{entry.where}: on_exit {on_exit!r} is not supported (only shutdown)")
        respawn_delay = entry.number("respawn_delay", 0.0)
        if respawn_delay < 0:
            raise LaunchError(f"{entry.where}: respawn_delay must be >= 0, got {respawn_delay:g}")
        retries = entry.number("respawn_max_retries", UNLIMITED_RESPAWNS)
        if not retries.is_integer() or retries < UNLIMITED_RESPAWNS:
            raise LaunchError(f"{entry.where}: respawn_max_retries must be an integer >= {UNLIMITED_RESPAWNS} "
                              f"({UNLIMITED_RESPAWNS}: unlimited), got {retries:g}")
        try:
            module = node_module(package, executable)
        except LaunchError as error:
            raise LaunchError(f"{entry.where}: {error}") from None
        remaps = tuple((substitute(str(r["from"]), entry.context), substitute(str(r["to"]), entry.context))
                       for r in entry.mappings("remap", {"from", "to"}, required={"from", "to"}))
        self.nodes.append(NodeSpec(
            name, package, executable, module, namespace, self._params(entry), remaps,
            tuple(shlex.split(entry.text("ros_args", default=""))), on_exit == "shutdown",
            entry.flag("respawn"), respawn_delay, int(retries), output,
            tuple(shlex.split(entry.text("args", default=""))), bool(given)))

    def _params(self, entry: _Entry) -> tuple[ParameterEntry, ...]:
        params: list[ParameterEntry] = []
        for param in entry.mappings("param", {"from", "name", "value", "param"}):
            if "from" in param:
                if set(param) != {"from"}:
                    raise LaunchError(f"{entry.where}: a param with 'from' takes nothing else, got {sorted(param)}")
                params.append(entry.path_of(substitute(str(param["from"]), entry.context), "param from"))
                continue
            values = _named(param, "", entry)
            if params and not isinstance(params[-1], Path):
                params[-1] = {**params[-1], **values}
            else:
                params.append(values)
        return tuple(params)


def _named(param: Mapping[str, Any], prefix: str, entry: _Entry) -> dict[str, Any]:
    """The parameters of one ``{name, value}`` (or ``{name, param: [...]}``) entry, by dotted name."""
    if "name" not in param:
        raise LaunchError(f"{entry.where}: a param needs 'from' or 'name'")
    name = prefix + substitute(str(param["name"]), entry.context)
    unknown = set(param) - {"name", "value", "param"}
    if unknown:
        raise LaunchError(f"{entry.where}: param attribute {sorted(unknown)[0]!r} is not supported (name, value, "
                          "param, from)")
    if ("value" in param) == ("param" in param):
        raise LaunchError(f"{entry.where}: param {name!r} needs a value or nested params (one of them)")
    if "param" in param:
        nested = param["param"]
        if not isinstance(nested, list):
            raise LaunchError(f"{entry.where}: the nested params of {name!r} must be a list")
        return {key: value for item in nested for key, value in _named(item, f"{name}.", entry).items()}
    return {name: _parameter_value(param["value"], f"{entry.where}: param {name!r}", entry.context)}


def _parameter_value(raw: Any, where: str, context: Context) -> Any:
    """A ``value`` as ``launch_ros`` evaluates it: text is substituted, then read as YAML."""
    if isinstance(raw, list):
        if not raw:
            raise LaunchError(f"{where}: an empty list has no type ROS can infer")
        items = [_parameter_value(item, where, context) if isinstance(item, str) else item for item in raw]
        if type(items[0]) not in SCALARS or any(type(item) is not type(items[0]) for item in items):
            raise LaunchError(f"{where}: a list's items must all be bool, all int, all float or all str, got {items}")
        return items
    if isinstance(raw, bool | int | float):
        return raw
    if not isinstance(raw, str):
        raise LaunchError(f"{where}: a value must be a scalar or a list, got {raw!r}")
    text = substitute(raw, context)
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        raise LaunchError(f"{where}: {text!r} does not read as a YAML value") from None
    if value is None:
        raise LaunchError(f"{where}: {raw!r} is empty once substituted (launch_ros cannot pass an empty value; "
                          "quote it: \"''\")")
    if isinstance(value, list):
        return _parameter_value(value, where, context)
    if type(value) not in SCALARS:
        raise LaunchError(f"{where}: {text!r} reads as {type(value).__name__}, not a parameter value")
    return value


@dataclass
class _Entry:
    """One tag of a launch file while it is read: its attributes, checked against :data:`TAGS`."""

    path: Path
    tag: str
    attributes: Any
    context: Context
    where: str = ""

    def __post_init__(self) -> None:
        self.where = f"{self.path}: {self.tag}"
        if not isinstance(self.attributes, dict):
            raise LaunchError(f"{self.where}: its attributes must be a mapping")
        unknown = sorted(set(self.attributes) - TAGS[self.tag] - CONDITIONS)
        if unknown:
            raise LaunchError(f"{self.where}: attribute {unknown[0]!r} is not supported by fiper launch "
                              f"({self.tag} takes {', '.join(sorted(TAGS[self.tag] | CONDITIONS))})")

    def applies(self) -> bool:
        """Whether the tag's ``if`` / ``unless`` let it run."""
        return (self.flag("if") if "if" in self.attributes else True) and not (
            self.flag("unless") if "unless" in self.attributes else False)

    def optional(self, name: str) -> Any:
        return self.attributes.get(name)

    def text(self, name: str, *, literal: bool = False, default: str | None = None) -> str:
        """The attribute as text with its substitutions evaluated (``literal``: none allowed)."""
        raw = self.attributes.get(name, default)
        if raw is None:
            raise LaunchError(f"{self.where}: needs {name!r}")
        if isinstance(raw, (dict, list)):
            raise LaunchError(f"{self.where}: {name!r} must be text, got {raw!r}")
        text = _text(raw)
        if literal:
            if has_substitution(text):
                raise LaunchError(f"{self.where}: {name!r} must be literal, got {text!r}")
            return text
        return substitute(text, self.context)

    def flag(self, name: str) -> bool:
        text = self.text(name, default="false").lower()
        if text not in ("true", "false", "1", "0"):
            raise LaunchError(f"{self.where}: {name} must be true or false, got {text!r}")
        return text in ("true", "1")

    def number(self, name: str, default: float) -> float:
        text = self.text(name, default=str(default))
        try:
            return float(text)
        except ValueError:
            raise LaunchError(f"{self.where}: {name} must be a number, got {text!r}") from None

    def mappings(self, name: str, allowed: set[str], required: frozenset[str] | set[str] = frozenset()
                 ) -> list[dict[str, Any]]:
        """The attribute as a list of mappings with keys among ``allowed`` (and every one of ``required``)."""
        items = self.attributes.get(name, [])
        if not isinstance(items, list) or not all(isinstance(item, dict) for item in items):
            raise LaunchError(f"{self.where}: {name!r} must be a list of mappings")
        for item in items:
            unknown, missing = set(item) - allowed, required - set(item)
            if unknown or missing:
                problem = f"attribute {sorted(unknown)[0]!r} is not supported" if unknown \
                    else f"needs {sorted(missing)[0]!r}"
                raise LaunchError(f"{self.where}: {name} entry {item}: {problem}")
        return items

    def path_of(self, text: str, what: str) -> Path:
        """A file named by ``text``: it must be absolute and exist."""
        path = Path(text)
        if not path.is_absolute():
            raise LaunchError(f"{self.where}: {what} {text!r} is relative: write $(dirname)/{text} or "
                              "$(find-pkg-share PKG)/... so that it means one file from any directory")
        if not path.is_file():
            raise LaunchError(f"{self.where}: {what}: no such file {path}")
        return path
