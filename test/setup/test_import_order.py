"""Import order in every module of the project: within each group of consecutive import lines (groups are
separated by a blank line: standard library, third party, first party, ``from .`` relative), the ``import X``
statements come first, then the ``from X import ...`` ones, each sorted by module name (case folded). The
layout moves of issue #20 left eleven files unsorted; this keeps them so."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SOURCES = sorted(p for folder in ("fiper_ros/fiper_ros", "sim_bridge/sim_bridge", "test", "tools")
                 for p in (ROOT / folder).rglob("*.py") if "__pycache__" not in p.parts)


def _module(node: ast.Import | ast.ImportFrom) -> str:
    if isinstance(node, ast.Import):
        return node.names[0].name
    return "." * node.level + (node.module or "")


def unsorted_groups(source: str) -> list[list[str]]:
    """The groups of top-level imports of ``source`` that are not in order (each as its modules, as written)."""
    lines = source.splitlines()
    body = [n for n in ast.parse(source).body if isinstance(n, (ast.Import, ast.ImportFrom))
            and _module(n) != "__future__"]
    groups: list[list[ast.Import | ast.ImportFrom]] = []
    for node in body:
        previous = groups[-1][-1] if groups else None
        contiguous = previous is not None and node.lineno == previous.end_lineno + 1 and \
            lines[node.lineno - 2].strip() != ""
        if contiguous:
            groups[-1].append(node)
        else:
            groups.append([node])

    def key(node: ast.Import | ast.ImportFrom) -> tuple[bool, str]:
        return isinstance(node, ast.ImportFrom), _module(node).lower()

    return [[_module(n) for n in group] for group in groups if group != sorted(group, key=key)]


def test_the_rule_by_hand() -> None:
    assert unsorted_groups("import os\nimport sys\nfrom pathlib import Path\n") == []
    assert unsorted_groups("from b import x\nfrom a import y\n") == [["b", "a"]]
    assert unsorted_groups("from a import x\nimport b\n") == [["a", "b"]]  # `import` lines first
    assert unsorted_groups("from b import x\n\nfrom a import y\n") == []  # two groups
    assert unsorted_groups("from fiper_ros.nodes import x\nfrom fiper_ros.interface import (\n    y)\n") \
        == [["fiper_ros.nodes", "fiper_ros.interface"]]


@pytest.mark.parametrize("path", SOURCES, ids=lambda p: str(p.relative_to(ROOT)))
def test_imports_are_in_order(path: Path) -> None:
    assert unsorted_groups(path.read_text()) == []
