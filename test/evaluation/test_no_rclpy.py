"""The evaluation engine and the baselines stay free of ROS."""

from __future__ import annotations

import pkgutil
import subprocess
import sys

import fiper_ros.baselines
import fiper_ros.evaluation


def test_evaluation_and_baselines_never_import_rclpy() -> None:
    modules = [f"fiper_ros.baselines.{m.name}" for m in pkgutil.iter_modules(fiper_ros.baselines.__path__)]
    modules += [f"fiper_ros.evaluation.{m.name}" for m in pkgutil.iter_modules(fiper_ros.evaluation.__path__)]
    modules += ["fiper_ros.commands.evaluate"]  # fiper evaluate's command module (was fiper_ros.evaluation.cli)
    assert "fiper_ros.commands.evaluate" in modules and "fiper_ros.baselines.stac" in modules
    code = "; ".join([f"import {m}" for m in modules] + ["import sys", "assert 'rclpy' not in sys.modules"])
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
