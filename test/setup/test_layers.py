"""The import layers of fiper_ros and sim_bridge (docs/architecture.md): dependencies only point down.

Every import of every module (also those inside functions and under ``TYPE_CHECKING``: a lazy import is
still a dependency) is read with ``ast``. A *unit* is a package of ``fiper_ros`` (``core``, ``bagio``, ...),
one of its top-level modules (``cli``, ``errors``, ...), ``fiper_ros`` itself (its ``__init__``: the version) or
``sim_bridge``. :data:`LAYERS` is the one place the allowed edges are written down: a unit may import units
of lower layers only, never one of its own layer or above, so no two units can import each other.
"""
from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from collections.abc import Iterator
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGES = {"fiper_ros": ROOT / "fiper_ros" / "fiper_ros", "sim_bridge": ROOT / "sim_bridge" / "sim_bridge"}

#: Lowest first. A unit may import the units of the layers below its own.
LAYERS: tuple[tuple[str, ...], ...] = (
    ("fiper_ros", "errors"),  # the version; the root of the user errors (FiperError)
    ("core", "interface", "data_paths", "cluster"),  # the method; the wire; data paths; the Ray cluster
    ("runtime", "baselines", "view", "platform"),  # streaming rules without rclpy; the comparison methods; the live
    # view; processes, DDS domains and shared memory (below the nodes, the launcher and the clients that all use it)
    ("bagio", "policy", "publishing"),  # bag I/O without rclpy; the generative policies; a policy's publishing side
    ("converters", "evaluation", "nodes"),  # foreign data -> rollouts; offline evaluation; the rclpy shells
    ("launcher", "sim_bridge"),  # launch files and node processes; the simulator side
    ("client",),  # talking to a running suite
    ("commands",),  # one module per fiper sub-command
    ("cli", "bench", "examples"),  # the fiper entry point; benchmarks; example user code
)
LEVEL = {unit: level for level, units in enumerate(LAYERS) for unit in units}
#: Optional dependencies: the only modules that may import each, and only inside a function, so that importing any
#: module (a node, the core, a command that was not asked for it) never loads it. ``ray``: the parallel offline
#: work on a Ray cluster (docs/scale.md).
OPTIONAL_IMPORTS: dict[str, tuple[str, ...]] = {
    "ray": ("fiper_ros.cluster", "sim_bridge.ray_runner", "fiper_ros.commands.replay_fleet",
            "fiper_ros.bench.scale_bench", "fiper_ros.evaluation.distributed"),
}
#: Units that must import without rclpy (the pure core, the streaming rules, bag I/O, evaluation, the live view).
RCLPY_FREE = ("core", "runtime", "bagio", "converters", "evaluation", "view")


def modules() -> Iterator[tuple[str, Path]]:
    """``(dotted name, file)`` of every module of both packages."""
    for top, root in PACKAGES.items():
        for path in sorted(root.rglob("*.py")):
            parts = path.relative_to(root.parent).with_suffix("").parts
            yield ".".join(parts[:-1] if parts[-1] == "__init__" else parts), path


def imports(name: str, path: Path) -> set[str]:
    """The dotted names ``name`` imports (relative imports resolved; ``from X import y`` gives ``X.y``, which
    may be a module or a name in ``X``)."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            found |= {base} | {f"{base}.{alias.name}" for alias in node.names}
    return found


def unit_of(name: str) -> str | None:
    """The unit of a dotted module name, or ``None`` outside the two packages."""
    parts = name.split(".")
    if parts[0] == "sim_bridge":
        return "sim_bridge"
    if parts[0] != "fiper_ros":
        return None
    if len(parts) == 1:
        return "fiper_ros"
    if (PACKAGES["fiper_ros"] / parts[1]).is_dir() or (PACKAGES["fiper_ros"] / f"{parts[1]}.py").is_file():
        return parts[1]
    return "fiper_ros"  # a name of fiper_ros/__init__.py (``from fiper_ros import __version__``)


def unit_edges() -> dict[tuple[str, str], list[str]]:
    """``(importer, imported)`` units -> the modules that make the edge."""
    edges: dict[tuple[str, str], list[str]] = {}
    for name, path in modules():
        source = unit_of(name)
        assert source is not None
        for target in {unit_of(t) for t in imports(name, path)} - {None, source}:
            edges.setdefault((source, target), []).append(name)  # type: ignore[arg-type]
    return edges


def test_every_unit_has_a_layer() -> None:
    units = {unit_of(name) for name, _ in modules()}
    assert units - set(LEVEL) == set(), "a new package or top-level module: give it a layer in LAYERS"
    assert set(LEVEL) - units == set(), "LAYERS names a unit that does not exist"


def test_imports_only_point_down() -> None:
    upward = [f"{source} (layer {LEVEL.get(source)}) imports {target} (layer {LEVEL.get(target)}): "
              f"{', '.join(sorted(where))}" for (source, target), where in sorted(unit_edges().items())
              if source not in LEVEL or target not in LEVEL or LEVEL[target] >= LEVEL[source]]
    assert upward == []


def test_no_import_cycles_between_modules() -> None:
    """Within a unit too: no module imports (directly or through others) a module that imports it."""
    names = dict(modules())
    graph = {name: {t for t in imports(name, path) if t in names and t != name} for name, path in names.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        for other in graph[node]:
            if other not in index:
                visit(other)
                low[node] = min(low[node], low[other])
            elif other in stack:
                low[node] = min(low[node], index[other])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            # a package's __init__ importing its own submodules is no cycle of concern unless they import it back
            if len(component) > 1:
                cycles.append(sorted(component))

    for name in sorted(graph):
        if name not in index:
            visit(name)
    assert cycles == []


def optional_imports(path: Path) -> list[tuple[str, bool]]:
    """``(top-level package, inside a function)`` of every import in ``path`` of a package of
    :data:`OPTIONAL_IMPORTS`."""
    found = []

    def visit(node: ast.AST, in_function: bool) -> None:
        names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                 else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level else [])
        found.extend((top, in_function) for top in {n.split(".")[0] for n in names} if top in OPTIONAL_IMPORTS)
        for child in ast.iter_child_nodes(node):
            visit(child, in_function or isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)))

    visit(ast.parse(path.read_text(), str(path)), False)
    return found


def test_optional_dependencies_are_imported_lazily_by_their_modules_only() -> None:
    wrong = sorted({f"{name} imports {package}" + ("" if lazy else " at module level")
                    for name, path in modules() for package, lazy in optional_imports(path)
                    if name not in OPTIONAL_IMPORTS[package] or not lazy})
    assert wrong == []


def test_the_modules_allowed_an_optional_import_exist() -> None:
    names = {name for name, _ in modules()}
    assert {m for allowed in OPTIONAL_IMPORTS.values() for m in allowed} - names == set()


def test_the_optional_import_rule_sees_module_level_and_lazy_imports(tmp_path: Path) -> None:
    source = tmp_path / "m.py"
    source.write_text("import os\nimport ray.util\nif os:\n    from ray import get\n"
                      "def f():\n    import ray\n    from os import path\n")
    assert optional_imports(source) == [("ray", False), ("ray", False), ("ray", True)]


@pytest.mark.parametrize("unit", RCLPY_FREE)
def test_units_import_without_rclpy(unit: str) -> None:
    """Every module of ``unit`` imports in a process where rclpy cannot be imported."""
    code = textwrap.dedent(f"""
        import importlib, pkgutil, sys

        class NoRclpy:
            def find_spec(self, name, path=None, target=None):
                if name == "rclpy" or name.startswith("rclpy."):
                    raise ImportError("rclpy is blocked in this test")

        sys.meta_path.insert(0, NoRclpy())
        package = importlib.import_module("fiper_ros.{unit}")
        for info in pkgutil.walk_packages(package.__path__, "fiper_ros.{unit}."):
            importlib.import_module(info.name)
        assert "rclpy" not in sys.modules
    """)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, check=False)
    assert result.returncode == 0, result.stderr[-2000:]


def test_every_package_names_its_public_face() -> None:
    """Each package's ``__init__.py`` has an ``__all__``; every name in it is a submodule or defined there."""
    problems = []
    for name, path in modules():
        if path.name != "__init__.py":
            continue
        tree = ast.parse(path.read_text())
        declared = [node.value for node in tree.body if isinstance(node, ast.Assign)
                    and any(isinstance(t, ast.Name) and t.id == "__all__" for t in node.targets)]
        if not declared:
            problems.append(f"{name}: no __all__")
            continue
        defined = {t.id for node in tree.body if isinstance(node, ast.Assign) for t in node.targets
                   if isinstance(t, ast.Name)}
        defined |= {node.target.id for node in tree.body if isinstance(node, ast.AnnAssign)
                    and isinstance(node.target, ast.Name)}
        defined |= {node.name for node in tree.body if isinstance(node, (ast.FunctionDef, ast.ClassDef))}
        defined |= {(a.asname or a.name) for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))
                    for a in node.names}
        for entry in ast.literal_eval(declared[0]):
            if entry not in defined and not ((path.parent / f"{entry}.py").is_file()
                                             or (path.parent / entry / "__init__.py").is_file()):
                problems.append(f"{name}.__all__: {entry!r} is neither a submodule nor defined there")
    assert problems == []
