"""``fiper launch`` on each shipped launch file (fiper_ros/launch/, sim_bridge/launch/; #21) brings its nodes ACTIVE
over real DDS on loopback, started from a directory that has nothing of the repository: the defaults come through
``$(find-pkg-share fiper_ros)`` (the installed calibration and model), arguments through ``$(var ...)``; a scoring
node that dies is respawned and ACTIVE again; ``name:=value`` arguments reach the nodes (a relative calibration of
the working directory, the observation-only suite)."""
from __future__ import annotations

import os
import signal
from pathlib import Path

import pytest
from ament_index_python.packages import get_package_share_directory

from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import OBSERVATION_ONLY
from helpers.diagnostics import DiagnosticsListener, up
from helpers.launch import Launch
from helpers.synthetic import make_calibration

ROOT = Path(os.environ["FIPER_ROOT"])
LAUNCH = ROOT / "fiper_ros" / "launch"
SHARE = Path(get_package_share_directory("fiper_ros"))
#: Seconds for a launch's nodes to report ACTIVE (six processes, torch and MuJoCo among them, on a loaded machine).
READY_S = 240.0


def wait_up(listener: DiagnosticsListener, launch: Launch, fqns: list[str]) -> dict[str, dict[str, str]]:
    """Wait until every node of ``fqns`` reported ACTIVE; their last statuses."""
    def all_up() -> bool:
        return all(up(listener.statuses, fqn, fqn.rsplit("/", 1)[1]) for fqn in fqns) or launch.proc.poll() is not None

    listener.spin_until(all_up, READY_S)
    statuses = {fqn: listener.statuses.get(f"fiper: {fqn}", {}) for fqn in fqns}
    assert all(up(listener.statuses, fqn, fqn.rsplit("/", 1)[1]) for fqn in fqns), (statuses, launch.lines[-40:])
    return statuses


@pytest.mark.slow
def test_the_suite_with_its_defaults_from_another_directory_and_a_dead_node_respawned(
        tmp_path: Path, ros_domain: int, listener: DiagnosticsListener) -> None:
    shipped = load_calibration(SHARE / "models" / "sorting" / "calibration").content_hash
    launch = Launch(LAUNCH / "fiper.launch.yaml", ros_domain, cwd=tmp_path)
    nodes = ["/fiper/rnd_oe_node", "/fiper/ace_node", "/fiper/fusion_node"]
    try:
        statuses = wait_up(listener, launch, nodes)
        assert statuses["/fiper/rnd_oe_node"]["calibration_hash"] == statuses["/fiper/ace_node"]["calibration_hash"] \
            == shipped
        first = launch.pid_of("ace_node")
        os.kill(first, signal.SIGKILL)
        assert listener.spin_until(lambda: len(launch.pids_of("ace_node")) == 2, 30), launch.lines[-20:]
        assert f"[launch] ace_node exited with code {-signal.SIGKILL}" in launch.lines
        assert "[launch] respawning ace_node in 1 s" in launch.lines
        listener.statuses.pop("fiper: /fiper/ace_node", None)  # what the killed process said
        assert wait_up(listener, launch, ["/fiper/ace_node"])["/fiper/ace_node"]["calibration_hash"] == shipped
        assert launch.pid_of("ace_node") != first
    finally:
        status = launch.interrupt()
    assert status == 1, launch.lines[-20:]  # a node exited on its own (the killed one)


@pytest.mark.slow
def test_launch_arguments_reach_the_nodes_the_observation_only_suite_on_a_relative_calibration(
        tmp_path: Path, ros_domain: int, listener: DiagnosticsListener) -> None:
    mine = make_calibration(tmp_path / "mine", detectors=OBSERVATION_ONLY)
    launch = Launch(LAUNCH / "fiper.launch.yaml", ros_domain, cwd=tmp_path,
                    arguments={"calibration_dir": "mine", "observation_only": "true", "log_level": "debug"})
    try:
        statuses = wait_up(listener, launch, ["/fiper/rnd_oe_node", "/fiper/fusion_node"])
        assert statuses["/fiper/rnd_oe_node"]["calibration_hash"] == load_calibration(mine).content_hash
        assert any("fusing rnd_oe: alone, combine does not apply" in line for line in launch.lines)
        assert any("[DEBUG]" in line for line in launch.lines)  # log_level:=debug reached the nodes
        assert not launch.pids_of("ace_node")
    finally:
        status = launch.interrupt()
    assert status == 0, launch.lines[-20:]


@pytest.mark.slow
def test_the_demo_launch_file_brings_all_six_nodes_up(tmp_path: Path, ros_domain: int,
                                                      listener: DiagnosticsListener) -> None:
    launch = Launch(LAUNCH / "demo.launch.yaml", ros_domain, cwd=tmp_path)
    try:
        wait_up(listener, launch, ["/sim/bridge_node", "/fiper/policy_node", "/fiper/rnd_oe_node", "/fiper/ace_node",
                                   "/fiper/fusion_node", "/fiper/supervisor_node"])
    finally:
        status = launch.interrupt()
    assert status == 0, launch.lines[-20:]


@pytest.mark.slow
def test_the_bridge_and_policy_launch_files_with_arguments(tmp_path: Path, ros_domain: int,
                                                          listener: DiagnosticsListener) -> None:
    bridge = Launch(ROOT / "sim_bridge" / "launch" / "bridge.launch.yaml", ros_domain, cwd=tmp_path,
                    arguments={"images": "false", "realtime_factor": "0.0"})
    policy = Launch(LAUNCH / "policy.launch.yaml", ros_domain, cwd=tmp_path, arguments={"batch": "4"})
    try:
        statuses = wait_up(listener, bridge, ["/sim/bridge_node"])
        statuses |= wait_up(listener, policy, ["/fiper/policy_node"])
        assert statuses["/sim/bridge_node"]["mode"] == "fast", statuses
        assert statuses["/fiper/policy_node"]["batch_size"] == "4", statuses
        assert statuses["/fiper/policy_node"]["model"] == str(SHARE / "models" / "sorting"), statuses
    finally:
        statuses = [policy.interrupt(), bridge.interrupt()]
    assert statuses == [0, 0], (bridge.lines[-20:], policy.lines[-20:])
