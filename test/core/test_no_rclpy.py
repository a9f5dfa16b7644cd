"""fiper_ros.core, fiper_ros.runtime and fiper_ros.policy stay free of ROS: importing every submodule
must not load rclpy (the nodes are thin shells around them)."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import pytest


@pytest.mark.parametrize(("package", "expected"), [
    ("fiper_ros.core", {"monitor", "calibration"}),
    ("fiper_ros.runtime", {"validation", "observation_sync"}),
    ("fiper_ros.policy", {"policy", "session"}),
])
def test_package_never_imports_rclpy(package: str, expected: set[str]) -> None:
    names = {m.name for m in pkgutil.iter_modules(importlib.import_module(package).__path__)}
    assert expected <= names
    check = ["import sys", "assert 'rclpy' not in sys.modules, 'rclpy imported'"]
    code = "; ".join([f"import {package}.{name}" for name in sorted(names)] + check)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
