"""fiper_ros.core stays free of ROS: importing every submodule must not load rclpy."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import fiper_ros.core


def test_core_never_imports_rclpy() -> None:
    modules = sorted(f"fiper_ros.core.{m.name}" for m in pkgutil.iter_modules(fiper_ros.core.__path__))
    assert "fiper_ros.core.monitor" in modules and "fiper_ros.core.calibration" in modules
    check = ["import sys", "assert 'rclpy' not in sys.modules, 'rclpy imported'"]
    code = "; ".join([f"import {m}" for m in modules] + check)
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
