"""Each package's package.xml declares what its code needs (#21): every ROS package a Python module imports as an
exec_depend, every third-party Python package as its rosdep key, or (without a key) by its pip name in README.md;
fiper_msgs depends on the packages its interfaces use."""
from __future__ import annotations

import ast
import os
import re
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from ament_index_python.packages import get_packages_with_prefixes

ROOT = Path(os.environ["FIPER_ROOT"])
PYTHON_PACKAGES = ("fiper_ros", "sim_bridge")
#: Third-party modules with a rosdep key (ros/rosdistro rosdep/python.yaml; pinocchio is a ROS package).
ROSDEP_KEYS = {"numpy": "python3-numpy", "yaml": "python3-yaml", "matplotlib": "python3-matplotlib",
               "pandas": "python3-pandas", "PIL": "python3-pil", "pinocchio": "pinocchio"}
#: Third-party modules without a rosdep key -> their pip package, which README.md names.
PIP_ONLY = {"torch": "torch", "rosbags": "rosbags", "mcap": "mcap", "pyarrow": "pyarrow", "mujoco": "mujoco",
            "foxglove": "foxglove-sdk", "ray": "ray"}
#: Imports not declared on purpose: fiper_ros's sim tools import sim_bridge, which exec_depends on fiper_ros
#: (colcon cannot order the cycle; both come from this repository).
UNDECLARED = {("fiper_ros", "sim_bridge")}


def imported_modules(package: str) -> set[str]:
    """Top-level names of the absolute imports in ``package``'s Python code (function-level ones included)."""
    names: set[str] = set()
    for path in (ROOT / package / package).rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                names |= {alias.name.split(".")[0] for alias in node.names}
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names.add(node.module.split(".")[0])
    return names - set(sys.stdlib_module_names) - {package}


def declared(package: str, tags: tuple[str, ...] = ("exec_depend", "depend")) -> set[str]:
    root = ET.parse(ROOT / package / "package.xml").getroot()
    return {element.text.strip() for tag in tags for element in root.iter(tag) if element.text}


def needed(package: str) -> tuple[set[str], set[str]]:
    """The keys ``package``'s imports need in package.xml, and the pip-only packages they need."""
    ros = set(get_packages_with_prefixes())
    keys, pip, unknown = set(), set(), set()
    for module in imported_modules(package):
        if (package, module) in UNDECLARED:
            continue
        if module in ros:
            keys.add(module)
        elif module in ROSDEP_KEYS:
            keys.add(ROSDEP_KEYS[module])
        elif module in PIP_ONLY:
            pip.add(PIP_ONLY[module])
        else:
            unknown.add(module)
    assert not unknown, f"{package} imports {sorted(unknown)}: add them to ROSDEP_KEYS or PIP_ONLY (and package.xml)"
    return keys, pip


def test_every_ros_package_and_python_dependency_the_code_imports_is_declared() -> None:
    readme = (ROOT / "README.md").read_text()
    for package in PYTHON_PACKAGES:
        keys, pip = needed(package)
        assert "rclpy" in keys and "fiper_msgs" in keys  # the scan sees the imports
        assert keys <= declared(package), (package, sorted(keys - declared(package)))
        for name in pip:
            assert re.search(rf"pip install [^`\n]*\b{re.escape(name)}\b", readme), (package, name)


def test_the_fiper_ros_scan_sees_the_imports_of_function_bodies_and_the_message_packages() -> None:
    keys, pip = needed("fiper_ros")
    # ament_index_python and pandas are imported only inside functions; builtin_interfaces in one module
    assert {"ament_index_python", "builtin_interfaces", "rcl_interfaces", "sensor_msgs", "python3-pandas"} <= keys
    assert {"torch", "rosbags", "mcap"} <= pip


def test_fiper_msgs_depends_on_the_packages_its_interfaces_use() -> None:
    used = set()
    for path in [*(ROOT / "fiper_msgs" / "msg").glob("*.msg"), *(ROOT / "fiper_msgs" / "srv").glob("*.srv")]:
        for line in path.read_text().splitlines():
            if m := re.match(r"\s*([a-z][a-z0-9_]*)/[A-Z]\w*", line):
                used.add(m.group(1))
    assert used and used <= declared("fiper_msgs"), sorted(used - declared("fiper_msgs"))


def test_a_package_with_launch_files_declares_what_ros2_launch_runs_them_with() -> None:
    for package in PYTHON_PACKAGES:
        files = sorted((ROOT / package / "launch").glob("*.launch.*"))
        assert files, package  # both ship launch files (#21)
        needed = {"launch_ros"} | ({"launch_yaml"} if any(f.suffix == ".yaml" for f in files) else set()) | (
            {"launch"} if any(f.suffix == ".py" for f in files) else set())
        assert needed <= declared(package), (package, sorted(needed - declared(package)))


def test_one_version() -> None:
    """``fiper_ros.__version__`` is the project's version: each package.xml (a ROS manifest, which cannot read a
    file) repeats it, fiper_ros's setup.py reads it and sim_bridge's reads its package.xml, so the built packages
    carry it too."""
    from importlib.metadata import version

    from fiper_ros import __version__

    manifests = {path.parent.name: ET.parse(path).getroot().findtext("version") for path in ROOT.glob("*/package.xml")}
    assert set(manifests) == {"fiper_ros", "fiper_msgs", "sim_bridge"}
    assert manifests == dict.fromkeys(manifests, __version__)
    assert {package: version(package) for package in PYTHON_PACKAGES} == dict.fromkeys(PYTHON_PACKAGES, __version__)
    assert all('version="' not in (ROOT / package / "setup.py").read_text() for package in PYTHON_PACKAGES)
