#!/usr/bin/env python3
"""Rewrite the wheel builder's absolute paths in the ROS 2 message wheels' CMake exports.

The ``ros-jazzy-*`` wheels export CMake targets whose include directories point at the machine that
built them (``/opt/python/cp311-cp311/...``). CMake refuses to configure a package that depends on
them ("includes non-existent path"). This script rewrites those two paths, in every ``*.cmake`` file
under ``<venv>/share``, to this interpreter's Python include directory and numpy's include directory.

Idempotent: a second run finds nothing to rewrite and changes no file.
Usage: python tools/fix_cmake_paths.py VENV
"""
from __future__ import annotations

import sys
import sysconfig
from pathlib import Path

BUILDER_PYTHON_INCLUDE = "/opt/python/cp311-cp311/include/python3.11"
BUILDER_NUMPY_INCLUDE = "/opt/python/cp311-cp311/lib/python3.11/site-packages/numpy/_core/include"


def replacements() -> dict[str, str]:
    """Map each builder path to the local path that replaces it."""
    import numpy  # imported here: the venv's numpy, after installation

    python_include = sysconfig.get_paths()["include"]
    if not Path(python_include, "Python.h").is_file():
        raise SystemExit(
            f"fix_cmake_paths: Python headers not found in {python_include}; "
            "install the Python development headers for this interpreter."
        )
    return {BUILDER_NUMPY_INCLUDE: numpy.get_include(), BUILDER_PYTHON_INCLUDE: python_include}


def fix(venv: Path) -> int:
    """Rewrite every CMake file under ``venv/share``; return the number of files changed."""
    table = replacements()
    changed = 0
    for path in sorted((venv / "share").rglob("*.cmake")):
        text = path.read_text(encoding="utf-8", errors="surrogateescape")
        new = text
        for old, local in table.items():
            new = new.replace(old, local)
        if new != text:
            path.write_text(new, encoding="utf-8", errors="surrogateescape")
            changed += 1
    return changed


def main() -> None:
    if len(sys.argv) != 2:
        raise SystemExit("usage: fix_cmake_paths.py VENV")
    venv = Path(sys.argv[1]).resolve()
    if not (venv / "share").is_dir():
        raise SystemExit(f"fix_cmake_paths: {venv}/share does not exist: is {venv} the project's venv?")
    changed = fix(venv)
    print(f"fix_cmake_paths: {changed} CMake file(s) rewritten in {venv}/share")


if __name__ == "__main__":
    main()
