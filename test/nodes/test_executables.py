"""``ros2 run``-style start of the nodes (#21): one console script per node where ``ros2 run PKG EXE`` looks
(``<prefix of PKG>/lib/PKG/EXE``), and a node started through it from an unrelated working directory, in
its own process over DDS on loopback, reaches ACTIVE."""
from __future__ import annotations

import os
import subprocess
from collections.abc import Mapping
from pathlib import Path

from ament_index_python.packages import get_package_prefix

from fiper_ros.core.calibration import load_calibration
from helpers.aggregator import analyzers_of
from helpers.dds import ros_env, stop
from helpers.diagnostics import DiagnosticsListener, up
from helpers.spin import spin_until

#: package -> its node executables.
EXECUTABLES = {
    "fiper_ros": ("rnd_oe_node", "ace_node", "fusion_node", "supervisor_node", "policy_node", "view_node"),
    "sim_bridge": ("bridge_node",),
}
SHIPPED = Path(os.environ["FIPER_ROOT"]) / "models"


def executable(package: str, name: str) -> Path:
    """Where ``ros2 run`` finds ``name`` of ``package``."""
    return Path(get_package_prefix(package)) / "lib" / package / name


def start(package: str, name: str, cwd: Path, domain: int, namespace: str, parameters: Mapping[str, str]
          ) -> subprocess.Popen[str]:
    """Start ``name`` through its installed executable in ``cwd``, as ``ros2 run`` would."""
    args = [str(executable(package, name)), "--ros-args", "-r", f"__ns:={namespace}"]
    for key, value in parameters.items():
        args += ["-p", f"{key}:={value}"]
    return subprocess.Popen(args, cwd=cwd, env=ros_env(domain), stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, start_new_session=True)


def test_every_node_has_an_executable_where_ros2_run_looks() -> None:
    for package, names in EXECUTABLES.items():
        for name in names:
            path = executable(package, name)
            assert path.is_file() and os.access(path, os.X_OK), path


def test_every_node_started_through_its_executable_from_another_directory_becomes_active(
        tmp_path: Path, calibration_dir: Path, ros_domain: int, listener: DiagnosticsListener) -> None:
    detector = {"calibration_dir": str(calibration_dir)}
    parameters: dict[str, Mapping[str, str]] = {"rnd_oe_node": detector, "ace_node": detector,
                                                "policy_node": {"model": str(SHIPPED / "sorting")},
                                                "view_node": {"port": "0"}}  # any free port: tests run side by side
    procs: dict[str, subprocess.Popen[str]] = {}
    fqns = {}
    try:
        for package, names in EXECUTABLES.items():
            namespace = "/sim" if package == "sim_bridge" else "/fiper"
            for name in names:
                procs[name] = start(package, name, tmp_path, ros_domain, namespace, parameters.get(name, {}))
                fqns[name] = f"{namespace}/{name}"
        spin_until(listener.executor, lambda: all(up(listener.statuses, fqns[n], n) for n in procs)
                   or any(p.poll() is not None for p in procs.values()), timeout=180, step=0.05)
        states = {n: up(listener.statuses, fqns[n], n) and procs[n].poll() is None for n in procs}
    finally:
        outputs = {name: stop(proc) for name, proc in procs.items()}
    for name, proc in procs.items():
        assert states[name], (name, listener.statuses.get(f"fiper: {fqns[name]}"), outputs[name][-3000:])
        assert proc.returncode == 0, (name, outputs[name][-3000:])  # Ctrl-C stops it cleanly
        # the status it published is grouped by one analyzer of config/diagnostics_aggregator.yaml
        assert len(analyzers_of(f"fiper: {fqns[name]}")) == 1, name


def test_scoring_nodes_started_elsewhere_load_the_shipped_calibration_named_relatively(
        tmp_path: Path, ros_domain: int, listener: DiagnosticsListener) -> None:
    """``calibration_dir: models/sorting/calibration`` from a directory without ``models/``: the
    installed copy in the package share (fiper_ros/data_paths.py), for the scoring nodes and the fusion node (which
    reads the detectors the calibration declares; it did not follow the rule); the policy node's default model
    likewise."""
    relative = "models/sorting/calibration"
    assert not (tmp_path / relative).exists()
    shipped = load_calibration(SHIPPED / "sorting" / "calibration").content_hash
    names = ("rnd_oe_node", "ace_node", "fusion_node", "policy_node")  # fusion: the detectors it declares
    procs = {name: start("fiper_ros", name, tmp_path, ros_domain, "/fiper",
                         {} if name == "policy_node" else {"calibration_dir": relative}) for name in names}
    try:
        spin_until(listener.executor, lambda: all(up(listener.statuses, f"/fiper/{n}", n) for n in names)
                   or any(p.poll() is not None for p in procs.values()), timeout=180, step=0.05)
        states = {n: dict(listener.statuses.get(f"fiper: /fiper/{n}", {})) for n in names}
    finally:
        outputs = {name: stop(proc) for name, proc in procs.items()}
    for name in names:
        assert states[name].get("lifecycle_state") == "active", (name, states[name], outputs[name][-3000:])
    for name in ("rnd_oe_node", "ace_node"):
        assert states[name]["calibration_hash"] == shipped, (name, states[name])
