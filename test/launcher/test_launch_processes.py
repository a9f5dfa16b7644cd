"""``fiper launch`` runs real node processes as ``launch_ros`` would: ``respawn_max_retries`` bounds the respawns (the
node is not started again after N, and the launcher says so), ``output: log`` sends a node's lines to its log file
under the launch's log directory (``$ROS_LOG_DIR/<launch>/<node>.log``) instead of the screen, ``output: both`` to
both. A node process that does not stop within the grace period prints where it hangs before it is killed."""
from __future__ import annotations

import os
import signal
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

from fiper_ros.launcher.config import NodeSpec
from fiper_ros.launcher.processes import ProcessGroup
from helpers.dds import ros_env
from helpers.launch import Launch, node_entry, write_launch

#: Seconds for a node process to start and log (rclpy imports on a loaded 2-core machine).
START_S = 120.0
#: What the fusion node logs once it has read its parameters.
FUSING = "fusing rnd_oe, ace"


@pytest.mark.slow
def test_a_node_killed_once_more_than_its_respawn_max_retries_is_not_started_again(
        tmp_path: Path, ros_domain: int) -> None:
    config = write_launch(tmp_path / "r.launch.yaml",
                          node_entry("fusion_node", respawn="true", respawn_delay=0.0, respawn_max_retries=2),
                          node_entry("supervisor_node"))
    launch = Launch(config, ros_domain)
    try:
        for kill in range(3):  # N + 1 kills: the first two are respawned, the third is final
            assert launch.wait_for(lambda k=kill: len(launch.pids_of("fusion_node")) == k + 1, START_S), \
                launch.lines[-20:]
            os.kill(launch.pid_of("fusion_node"), signal.SIGKILL)
        final = "[launch] not respawning fusion_node again: respawned 2 time(s), its respawn_max_retries 2"
        assert launch.wait_for(lambda: final in launch.lines, START_S), launch.lines[-20:]
        assert launch.lines.count("[launch] respawning fusion_node in 0 s") == 2
        assert launch.proc.poll() is None  # the other node keeps the launch running
        assert len(launch.pids_of("fusion_node")) == 3  # after the positive event above: no fourth start
    finally:
        status = launch.interrupt()
    assert status == 1, launch.lines[-20:]  # a node exited on its own
    assert len(launch.pids_of("fusion_node")) == 3, launch.lines[-20:]


@pytest.mark.slow
def test_output_log_writes_a_nodes_lines_to_its_log_file_and_both_to_the_screen_too(
        tmp_path: Path, ros_domain: int) -> None:
    both = node_entry("fusion_node", namespace="/both", output="both")
    config = write_launch(tmp_path / "o.launch.yaml", node_entry("fusion_node", output="log"),
                          {"node": {**both["node"], "name": "fusion_both"}})
    launch = Launch(config, ros_domain, env={"ROS_LOG_DIR": str(tmp_path / "logs")})
    try:
        def said() -> list[str]:
            return [line for line in list(launch.lines) if "'s output (output: " in line]

        assert launch.wait_for(lambda: len(said()) == 2, START_S), launch.lines[-20:]
        paths = {line.split("'s output", 1)[0].removeprefix("[launch] "): Path(line.rsplit(" goes to ", 1)[1])
                 for line in said()}
        directory = tmp_path / "logs" / paths["fusion_node"].parent.name
        assert paths == {"fusion_node": directory / "fusion_node.log", "fusion_both": directory / "fusion_both.log"}
        assert directory.name.endswith(f"-{launch.proc.pid}")  # <start time>-<host>-<launcher pid>, as launch_ros

        def logged(name: str) -> str:
            return paths[name].read_text() if paths[name].is_file() else ""

        assert launch.wait_for(lambda: FUSING in logged("fusion_node") and FUSING in logged("fusion_both"), START_S), \
            (launch.lines[-20:], logged("fusion_node"), logged("fusion_both"))
        assert f"[fiper.fusion_node]: {FUSING}" in logged("fusion_node")
        assert f"[both.fusion_both]: {FUSING}" in logged("fusion_both")
        assert launch.wait_for(lambda: any(FUSING in line for line in launch.lines), START_S)
        screen = [line for line in launch.lines if FUSING in line]  # both have logged it (above)
        assert len(screen) == 1 and screen[0].startswith("[fusion_both] ") and "[both.fusion_both]" in screen[0], \
            launch.lines[-20:]
    finally:
        status = launch.interrupt()
    assert status == 0, launch.lines[-20:]


@dataclass(frozen=True)
class ScriptSpec(NodeSpec):
    """A launch entry whose process is ``python -c SCRIPT``."""

    script: str = ""

    def command(self, params_dir: Path, enclave: bool = False) -> list[str]:
        return [sys.executable, "-c", self.script]


def script_group(tmp_path: Path, grace_s: float, name: str, script: str) -> tuple[ProcessGroup, list[str]]:
    """A launch of one :class:`ScriptSpec` named ``name``, its lines (the launcher's and the process's) collected."""
    group = ProcessGroup(grace_s=grace_s, params_dir=tmp_path, log_dir=tmp_path)
    lines: list[str] = []
    group.say = lines.append  # type: ignore[method-assign]
    group.start(ScriptSpec(name=name, package="fiper_ros", executable=name, module=name, namespace="/",
                           script=script))
    return group, lines


def wait_for(lines: list[str], text: str) -> bool:
    """Whether a line holding ``text`` comes within :data:`START_S`."""
    deadline = time.monotonic() + START_S
    while not any(text in line for line in list(lines)):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.05)
    return True


#: A node process (``run_node``) whose node never finishes its construction and ignores Ctrl-C meanwhile.
STUCK_NODE = """
import sys, time
from fiper_ros.platform.process import run_node

def stuck_in_construction():
    print("constructing", flush=True)
    while True:
        try:
            time.sleep(60)
        except KeyboardInterrupt:
            pass

sys.exit(run_node(stuck_in_construction, []))
"""


def test_a_node_that_does_not_stop_within_the_grace_period_prints_its_stacks_before_it_is_killed(
        tmp_path: Path, ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> None:
    for name, value in ros_env(ros_domain).items():
        monkeypatch.setenv(name, value)
    group, lines = script_group(tmp_path, 1.0, "stuck", STUCK_NODE)
    assert wait_for(lines, "[stuck] constructing"), lines
    group.stop()
    assert group.procs["stuck"].returncode == -signal.SIGKILL
    assert "[launch] stuck did not stop within 1 s: its stacks, then killing it" in lines
    # faulthandler's dump of the main thread, relayed with the node's other output
    assert wait_for(lines, "in stuck_in_construction"), lines


#: A process that ignores Ctrl-C and ends on the stacks signal (a node whose teardown ends within the stacks' wait).
ENDS_ON_STACKS = """
import os, signal, time
from fiper_ros.platform.dds import STACKS_SIGNAL
signal.signal(signal.SIGINT, signal.SIG_IGN)
signal.signal(STACKS_SIGNAL, lambda *_: os._exit(0))
print("waiting", flush=True)
time.sleep(60)
"""


def test_a_node_that_ends_while_printing_its_stacks_is_not_killed_and_the_launcher_goes_on(tmp_path: Path) -> None:
    """The demo's launcher crashed (ProcessLookupError) when the policy node ended in the stacks' wait: its
    process group was gone by the kill."""
    group, lines = script_group(tmp_path, 0.5, "late", ENDS_ON_STACKS)
    assert wait_for(lines, "[late] waiting"), lines
    group.stop()
    assert group.procs["late"].returncode == 0, lines
    assert "[launch] late did not stop within 0.5 s: its stacks, then killing it" in lines
