"""The node suite started for a replay (and for ``fiper demo`` and ``fiper collect --ros``): ``fiper launch`` of a
launch file, with its launch arguments, in a child process; and which of its nodes and topics a calibration's
detectors need.

A replay launches the installed ``launch/fiper.launch.yaml`` (or ``--launch FILE``, which declares the same
arguments) with ``use_sim_time:=true`` and the calibration's :func:`suite_arguments`: ``calibration_dir:=DIR`` and
the arguments that run exactly the scoring nodes of the detectors it declares (``observation_only:=true``: no ACE
node; ``progress:=true``: a progress node; ...). ``fiper demo`` and ``fiper collect --ros`` give
``launch/demo.launch.yaml`` (which includes the suite) the same. A robot model for joint-space
actions goes to the ACE node through :class:`~fiper_ros.launcher.overrides.Overrides` (the file has no argument
for it), so the nodes are exactly those of a normal launch.
"""
from __future__ import annotations

import collections
import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping
from pathlib import Path

from fiper_ros.core.calibration_file import Declared, declared
from fiper_ros.core.combine_mode import CombineMode
from fiper_ros.core.detectors import ACE, DETECTORS, RND_OE, SIGNAL_PREFIX, info
from fiper_ros.core.kinematics import RobotModel
from fiper_ros.interface.topics import JOINT_STATES_TOPIC, TOPICS, input_topic, score_topic
from fiper_ros.launcher.config import LaunchConfig, LaunchError, dump_launch, load_launch
from fiper_ros.launcher.overrides import Overrides, apply
from fiper_ros.platform.dds import PARENT_PID_ENV, interrupt_group, local_env

#: The scoring node's module of FIPER's pair (every other detector's is the generic detector node's); the fusion node.
DETECTOR_MODULES = {RND_OE: "fiper_ros.nodes.rnd_oe_node", ACE: "fiper_ros.nodes.ace_node"}
GENERIC_MODULE = "fiper_ros.nodes.detector_node"
ACE_MODULE = DETECTOR_MODULES[ACE]
FUSION_MODULE = "fiper_ros.nodes.fusion_node"
#: The installed launch file of the scoring suite (a node per declared detector, fusion).
SUITE_LAUNCH = "fiper.launch.yaml"
#: Lines of the suite's output kept for an error report.
KEPT_LINES = 200
#: The launcher's report of a node process it started.
STARTED = re.compile(r"\[launch\] started (\S+) \(pid (\d+)\)")
#: Launch arguments of the suite's file that add a detector's node (FIPER's pair: ``rnd_oe``, ``observation_only``).
DETECTOR_ARGUMENTS = ("logpzo", "pca_kmeans", "progress", "consistency", "elapsed")


def detector_topics(detector: str) -> tuple[str, tuple[str, ...], str]:
    """Per detector: the policy step's input its node scores, the other inputs only that node reads, its scores."""
    return input_topic(info(detector).reads), (JOINT_STATES_TOPIC,) if detector == ACE else (), score_topic(detector)


def detector_module(detector: str) -> str:
    """The module of ``detector``'s scoring node."""
    return DETECTOR_MODULES.get(detector, GENERIC_MODULE)


def declared_of(directory: Path | None) -> Declared:
    """The detectors the calibration in ``directory`` declares and how it combines them (FIPER's pair under
    ``and`` without one), read without loading its score models; a ``CalibrationError`` (one line naming the file)
    for a missing or unreadable calibration and one that declares no (or no supported) detector set."""
    return Declared(DETECTORS, CombineMode.AND.value) if directory is None else declared(directory)


def detectors_of(directory: Path | None) -> tuple[str, ...]:
    """The detectors of :func:`declared_of`."""
    return declared_of(directory).detectors


def scoring_modules(detectors: tuple[str, ...]) -> tuple[str, ...]:
    """The modules of the nodes that score and fuse ``detectors``: the scoring node of each, the fusion node."""
    return (*dict.fromkeys(detector_module(d) for d in detectors), FUSION_MODULE)


def suite_topics(detectors: tuple[str, ...]) -> tuple[str, ...]:
    """The bag schema's topics of a suite that scores ``detectors``: all but FIPER's pair's scores the suite has
    not, and the scores of the others it has."""
    others = {score_topic(d) for d in DETECTORS if d not in detectors}
    extra = tuple(score_topic(d) for d in detectors if d not in DETECTORS)
    return tuple(topic for topic in TOPICS if topic not in others) + extra


def suite_arguments(calibration: Path, detectors: tuple[str, ...]) -> dict[str, str]:
    """The launch arguments that give the suite ``calibration`` (absolute) and the scoring nodes of ``detectors``
    (those it declares): ``calibration_dir``, ``rnd_oe:=false`` without RND-OE, ``observation_only:=true`` without
    ACE, ``<detector>:=true`` for each other detector and ``use_signal:=true signal:=NAME`` for a logged signal
    (the suite's file runs one); :class:`LaunchError` for a set the file cannot run."""
    signals = [d.removeprefix(SIGNAL_PREFIX) for d in detectors if info(d).reads == "signal"]
    if len(signals) > 1:
        raise LaunchError(f"the calibration declares {len(signals)} logged signals ({', '.join(signals)}); the suite's "
                       "launch file runs the node of one: launch the others' detector nodes beside it")
    arguments = {"calibration_dir": str(calibration.resolve())}
    arguments |= {"rnd_oe": "false"} if RND_OE not in detectors else {}
    arguments |= {"observation_only": "true"} if ACE not in detectors else {}
    arguments |= {name: "true" for name in DETECTOR_ARGUMENTS if name in detectors}
    arguments |= {"use_signal": "true", "signal": signals[0]} if signals else {}
    return arguments


def robot_parameters(robot: RobotModel | None) -> dict[str, dict[str, str]]:
    """The ``robot``'s URDF and EE frame on the ACE node's module (for joint-space actions); none without one."""
    return {} if robot is None else {ACE_MODULE: {"urdf_path": str(Path(robot.urdf).resolve()),
                                                  "ee_frame": robot.ee_frame}}


def installed_launch(name: str = SUITE_LAUNCH) -> Path:
    """The installed ``fiper_ros/launch/<name>`` (default: the scoring suite)."""
    from ament_index_python.packages import get_package_share_directory  # noqa: PLC0415

    return Path(get_package_share_directory("fiper_ros")) / "launch" / name


def replay_launch(launch: Path, calibration: Path, detectors: tuple[str, ...],
                  robot: RobotModel | None = None, arguments: Mapping[str, str] | None = None) -> LaunchConfig:
    """The suite of ``launch`` for a replay on ``calibration`` (declaring ``detectors``): sim time, the ``robot``'s
    URDF and EE frame on the ACE node, and the launch ``arguments`` given (the live view's)."""
    given = {"use_sim_time": "true", **suite_arguments(calibration, detectors), **(arguments or {})}
    return apply(load_launch(launch, given), Overrides(by_module=robot_parameters(robot)))


def replay_config(launch: Path, calibration: Path, detectors: tuple[str, ...], out: Path,
                  robot: RobotModel | None = None, arguments: Mapping[str, str] | None = None) -> Path:
    """Write :func:`replay_launch` to ``out``, read with the launch ``arguments`` given too (the live view's)."""
    try:
        return dump_launch(replay_launch(launch, calibration, detectors, robot, arguments), out)
    except LaunchError as error:
        raise LaunchError(f"launch file {launch}: {error}") from error


class SuiteProcess:
    """``fiper launch`` of a launch file (with launch ``arguments``) in its own process group, in ``domain``."""

    def __init__(self, config: Path, domain: int, echo: bool, log: Path | None = None,
                 arguments: Mapping[str, str] | None = None) -> None:
        """``echo``: copy the suite's output to stderr; ``log``: and write all of it to this file."""
        self.lines: collections.deque[str] = collections.deque(maxlen=KEPT_LINES)
        self._echo = echo
        self._log = log.open("w") if log is not None else None
        named = [f"{name}:={value}" for name, value in (arguments or {}).items()]
        self.proc = subprocess.Popen(  # noqa: S603 - our own launcher
            [sys.executable, "-m", "fiper_ros.cli", "launch", str(config), *named, "--grace", "5"],
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
            interrupt_group(self.proc.pid)
            try:
                self.proc.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
        status = self.proc.wait()
        self._reader.join(timeout=5.0)
        if self._log is not None:
            self._log.close()
        return status
