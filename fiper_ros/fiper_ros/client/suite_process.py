"""The node suite started for a replay (and for ``fiper demo`` and ``fiper collect --ros``): ``fiper launch``
in a child process.

For a replay the launch YAML (default: the installed suite of the calibration's detectors,
``config/suite.yaml`` or, observation-only, ``config/suite_obs.yaml``) is read with the launcher's own parser
and written again with ``use_sim_time: true`` and the replay's calibration directory set on the scoring
nodes and the fusion node, so the nodes are exactly those of a normal launch.
"""
from __future__ import annotations

import collections
import os
import re
import signal
import subprocess
import sys
import threading
from pathlib import Path

import yaml

from fiper_ros.bagio.errors import BagError
from fiper_ros.core.detectors import DETECTORS, OBSERVATION_ONLY
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.dds import PARENT_PID_ENV, local_env
from fiper_ros.launcher.config import LaunchError
from fiper_ros.launcher.overrides import Overrides, rewrite

#: Nodes that take ``calibration_dir``: the scoring nodes, and the fusion node (for the detectors it fuses).
ACE_MODULE = "fiper_ros.nodes.ace_node"
CALIBRATED_MODULES = ("fiper_ros.nodes.rnd_oe_node", ACE_MODULE, "fiper_ros.nodes.fusion_node")
#: The installed launch YAML of the scoring suite of each detector set a calibration may declare.
SUITE_CONFIGS = {DETECTORS: "suite.yaml", OBSERVATION_ONLY: "suite_obs.yaml"}
#: Lines of the suite's output kept for an error report.
KEPT_LINES = 200
#: The launcher's report of a node process it started.
STARTED = re.compile(r"\[launch\] started (\S+) \(pid (\d+)\)")


def installed_config(name: str = "suite.yaml") -> Path:
    """The installed ``fiper_ros/config/<name>`` (default: the scoring suite)."""
    from ament_index_python.packages import get_package_share_directory  # noqa: PLC0415

    return Path(get_package_share_directory("fiper_ros")) / "config" / name


def replay_config(config: Path, calibration: Path, out: Path, robot: RobotModel | None = None) -> Path:
    """Write ``config`` with sim time and ``calibration`` on the scoring nodes to ``out``, and the
    ``robot``'s URDF and EE frame on the ACE node (for joint-space actions)."""
    detector = {"calibration_dir": str(calibration.resolve())}
    parameters = {module: detector for module in CALIBRATED_MODULES}
    if robot is not None:
        parameters[ACE_MODULE] = detector | {"urdf_path": str(Path(robot.urdf).resolve()), "ee_frame": robot.ee_frame}
    try:
        return rewrite(config, Overrides(by_module=parameters, use_sim_time=True), out)
    except (LaunchError, yaml.YAMLError) as error:
        raise BagError(f"launch config {config}: {error}") from error


class SuiteProcess:
    """``fiper launch`` of a replay config in its own process group, in ``domain``."""

    def __init__(self, config: Path, domain: int, echo: bool, log: Path | None = None) -> None:
        """``echo``: copy the suite's output to stderr; ``log``: and write all of it to this file."""
        self.lines: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._echo = echo
        self._log = log.open("w") if log is not None else None
        self.proc = subprocess.Popen(  # noqa: S603 - our own launcher
            [sys.executable, "-m", "fiper_ros.cli", "launch", str(config), "--grace", "5"],
            env=local_env(domain) | {PARENT_PID_ENV: str(os.getpid())},  # a killed client takes its suite along
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if self._log is not None:
                self._log.write(line)
                self._log.flush()
            if self._echo:
                print(line.rstrip(), file=sys.stderr, flush=True)

    def alive(self) -> bool:
        """Whether the launcher still runs."""
        return self.proc.poll() is None

    def output(self) -> str:
        """The last lines of the suite's output."""
        return "\n".join(self.lines)

    def node_pids(self) -> dict[str, int]:
        """Node name -> process id, from the launcher's ``started`` reports (call it soon after the start:
        only the last :data:`KEPT_LINES` lines are kept)."""
        return {match.group(1): int(match.group(2)) for line in list(self.lines)
                if (match := STARTED.match(line)) is not None}

    def node_exits(self) -> list[str]:
        """The launcher's reports of nodes that exited, e.g. ``rnd_oe_node exited with code -9``."""
        if self.proc.poll() is not None:
            self._reader.join(timeout=1.0)  # the launcher's last lines
        return [line.removeprefix("[launch] ") for line in list(self.lines)
                if line.startswith("[launch] ") and " exited with code " in line]

    def stop(self, timeout_s: float = 20.0) -> int:
        """Ctrl-C the launcher (it stops its nodes), SIGKILL the group if it hangs; its exit status."""
        if self.proc.poll() is None:
            os.killpg(self.proc.pid, signal.SIGINT)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
        status = self.proc.wait()
        self._reader.join(timeout=5.0)
        if self._log is not None:
            self._log.close()
        return status
