"""Issue #24, start-up: a node process (and a tool's rclpy session) points Fast DDS at the suite's discovery
profile unless the user has a profile of their own, says so and logs the seconds from its exec to ACTIVE; ``fiper launch`` starts its nodes
without importing numpy or pinocchio. (How fast that is, is ``make bench-nodes``'s figure, not a test's.)"""
from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from fiper_ros.data_paths import package_share
from fiper_ros.platform import process
from fiper_ros.platform import PlatformError
from fiper_ros.platform.dds import interrupt_group, local_env
from fiper_ros.platform.process import DISCOVERY_PROFILE, FASTDDS_PROFILES_ENV, process_age_s, use_discovery_profile

ROOT = Path(__file__).resolve().parents[2]
CALIBRATION = ROOT / "models" / "pusht" / "calibration"
OURS = package_share() / DISCOVERY_PROFILE  # type: ignore[operator]


@pytest.fixture
def clean_env(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> pytest.MonkeyPatch:
    """No Fast DDS profile variable, the default RMW, and a working directory without profiles files."""
    monkeypatch.delenv(FASTDDS_PROFILES_ENV, raising=False)
    monkeypatch.delenv("RMW_IMPLEMENTATION", raising=False)
    monkeypatch.chdir(tmp_path)
    return monkeypatch


def env_without_profile(domain: int) -> dict[str, str]:
    """A child's environment in ``domain`` without the profile variable (this test process has it set: conftest),
    as a console script started by hand would have it."""
    return {k: v for k, v in local_env(domain).items() if k != FASTDDS_PROFILES_ENV}


def test_the_profile_is_installed_in_the_share() -> None:
    assert OURS.is_file()
    assert "<leaseAnnouncement>" in OURS.read_text()


def test_without_settings_of_the_user_the_suite_profile_is_used(clean_env: pytest.MonkeyPatch) -> None:
    assert use_discovery_profile() == OURS
    assert os.environ[FASTDDS_PROFILES_ENV] == str(OURS)
    assert use_discovery_profile() == OURS  # set by a parent (fiper launch's children): still in effect


def test_a_profile_of_the_user_wins(clean_env: pytest.MonkeyPatch, tmp_path: Path) -> None:
    theirs = tmp_path / "theirs.xml"
    theirs.write_text("<profiles/>")
    clean_env.setenv(FASTDDS_PROFILES_ENV, str(theirs))
    assert use_discovery_profile() is None
    assert os.environ[FASTDDS_PROFILES_ENV] == str(theirs)


@pytest.mark.parametrize("name", process.FASTDDS_DEFAULT_FILES)
def test_a_default_profiles_file_in_the_working_directory_wins(clean_env: pytest.MonkeyPatch, tmp_path: Path,
                                                               name: str) -> None:
    (tmp_path / name).write_text("<profiles/>")
    assert use_discovery_profile() is None
    assert FASTDDS_PROFILES_ENV not in os.environ


def test_another_rmw_is_left_alone(clean_env: pytest.MonkeyPatch) -> None:
    clean_env.setenv("RMW_IMPLEMENTATION", "rmw_cyclonedds_cpp")
    assert use_discovery_profile() is None
    assert FASTDDS_PROFILES_ENV not in os.environ


def test_a_tools_session_uses_the_profile(ros_domain: int) -> None:
    """A tool's rclpy session (fiper record, replay, demo, ...: ``RosSession``), started without the profile
    variable, points Fast DDS at the suite's profile as the nodes do (before, it stayed on Fast DDS's defaults and
    saw a node start up to 3 s late)."""
    env = env_without_profile(ros_domain)
    code = ("import os; from fiper_ros.client.ros_session import RosSession\n"
            "with RosSession('probe'):\n"
            f"    print(os.environ.get({FASTDDS_PROFILES_ENV!r}))")
    result = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120,
                            check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.splitlines()[-1] == str(OURS), result.stdout + result.stderr


def test_process_age_counts_from_the_exec() -> None:
    """A child that sleeps 0.5 s before it asks is at least that old (the kernel's tick: 10 ms)."""
    code = ("import time; time.sleep(0.5); from fiper_ros.platform.process import process_age_s; "
            "print(process_age_s())")
    age = float(subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                               timeout=60).stdout)
    assert 0.49 <= age < 60
    assert 0 <= process_age_s()


def test_a_node_process_uses_the_profile_and_logs_its_start_up(ros_domain: int) -> None:
    """The fusion node, started as a console script would be (no profile variable set): it names the profile,
    Fast DDS reads it without an error, and the node says ACTIVE with its seconds since exec."""
    env = env_without_profile(ros_domain)
    process = subprocess.Popen(
        [sys.executable, "-m", "fiper_ros.nodes.fusion_node", "--ros-args", "-r", "__ns:=/fiper",
         "-p", f"calibration_dir:={CALIBRATION}"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lines: list[str] = []
    try:
        assert process.stdout is not None
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not any("ACTIVE" in line for line in lines):
            line = process.stdout.readline()
            if not line:
                break
            lines.append(line)
    finally:
        started = "".join(lines)  # up to ACTIVE: a Ctrl-C in the transition's last step may print an error after it
        interrupt_group(process.pid)
        lines += process.communicate(timeout=30)[0].splitlines(keepends=True)
    output = "".join(lines)
    assert f"DDS discovery: Fast DDS profile {OURS}" in started, output
    assert "Error" not in started, output  # Fast DDS reports an unreadable profile as an XMLParser error
    active = [line for line in lines if "]: ACTIVE " in line]
    assert active and active[0].rstrip().endswith("s after the process started"), output
    assert 0 < float(active[0].split("]: ACTIVE ")[1].split()[0]) < 60


def test_fiper_launch_starts_without_numpy_or_pinocchio() -> None:
    """The launcher parses the shipped suite and finds its node modules with numpy and pinocchio refused (they
    took a third of its start-up before the nodes were started)."""
    code = """
import importlib.abc, sys
class Refuse(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split(".")[0] in ("numpy", "pinocchio"):
            raise ModuleNotFoundError(f"{name} is blocked by the test", name=name)
        return None
sys.meta_path.insert(0, Refuse())
from fiper_ros.cli import main
from fiper_ros.launcher.config import node_module
assert main(["launch", "fiper_ros/launch/fiper.launch.yaml", "--show-args"]) == 0
assert node_module("fiper_ros", "ace_node") == "fiper_ros.nodes.ace_node"
assert not {"numpy", "pinocchio"} & set(sys.modules)
print("ok")
"""
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=False,
                            cwd=ROOT)
    assert result.returncode == 0 and result.stdout.endswith("ok\n"), result.stdout + result.stderr


@pytest.mark.parametrize("kind", ["threads", "Events"])
def test_an_executor_kind_not_offered_is_a_platform_error(monkeypatch: pytest.MonkeyPatch, kind: str) -> None:
    """A user's error (the environment), named with its variable and the kinds offered; was a ValueError."""
    monkeypatch.setenv(process.EXECUTOR_ENV, kind)
    with pytest.raises(PlatformError) as raised:
        process.new_executor()
    assert str(raised.value) == f"FIPER_EXECUTOR={kind!r}: expected 'events' or 'single'"


def test_a_node_process_reports_a_user_error_in_one_line(ros_domain: int) -> None:
    """A user error that escapes the node's start-up (here the executor kind the environment names, refused after the
    node is built) is one line ``NODE: MESSAGE`` and exit status 2, as ``fiper`` reports one (was a traceback)."""
    env = {**env_without_profile(ros_domain), process.EXECUTOR_ENV: "threads"}
    result = subprocess.run([sys.executable, "-m", "fiper_ros.nodes.fusion_node", "--ros-args", "-r", "__ns:=/fiper"],
                            capture_output=True, text=True, timeout=120, check=False, cwd=ROOT, env=env)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr, result.stderr
    assert result.stderr.splitlines()[-1] == "fusion_node: FIPER_EXECUTOR='threads': expected 'events' or 'single'"
