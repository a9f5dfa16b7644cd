"""The workspace environment: the env script's shell, clear messages before set-up, loopback-only DDS."""
from __future__ import annotations

import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from helpers.dds import spawn_python, stop

ROOT = Path(os.environ["FIPER_ROOT"])


def _bash(script: str, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["bash", "-c", script], cwd=cwd, env=env, capture_output=True, text=True, timeout=120)


def _bare_env() -> dict[str, str]:
    """An environment as a fresh login shell has it: none of the workspace's variables."""
    keep = ("HOME", "USER", "LANG", "TERM")
    return {k: os.environ[k] for k in keep if k in os.environ} | {"PATH": "/usr/local/bin:/usr/bin:/bin"}


def test_env_script_shell_imports_the_interfaces() -> None:
    result = _bash(
        ". ./env.sh && python -c 'from fiper_msgs.msg import ActionChunkBatch, FailureAlarm; print(FailureAlarm.STATE_ALARM)'"
        " && echo \"$ROS_AUTOMATIC_DISCOVERY_RANGE $ROS_DOMAIN_ID\"",
        ROOT,
        _bare_env(),
    )
    assert result.returncode == 0, result.stderr
    lines = result.stdout.split()
    assert lines[0] == "1" and lines[1] == "LOCALHOST" and 1 <= int(lines[2]) <= 101


@pytest.mark.parametrize("command", [". ./env.sh", "bin/fiper doctor"])
def test_commands_before_setup_say_what_to_do(tmp_path: Path, command: str) -> None:
    checkout = tmp_path / "checkout"  # a clone in which 'make setup' never ran
    (checkout / "bin").mkdir(parents=True)
    shutil.copy(ROOT / "env.sh", checkout / "env.sh")
    shutil.copy(ROOT / "bin" / "fiper", checkout / "bin" / "fiper")
    result = _bash(command, checkout, _bare_env())
    assert result.returncode != 0
    assert "make setup" in result.stderr
    assert "Traceback" not in result.stderr + result.stdout


def test_fiper_without_the_built_interfaces_says_what_to_do(tmp_path: Path) -> None:
    env = _bare_env() | {"PYTHONPATH": str(ROOT / "fiper_ros")}
    result = subprocess.run(
        [str(ROOT / ".venv" / "bin" / "python"), "-c", "import sys; from fiper_ros.cli import main; sys.exit(main(['doctor']))"],
        env=env, capture_output=True, text=True, timeout=120, cwd=tmp_path,
    )
    assert result.returncode == 1
    assert "FAIL  fiper_msgs.msg" in result.stdout
    assert "FAIL  ROS_AUTOMATIC_DISCOVERY_RANGE" in result.stdout
    assert "Traceback" not in result.stderr


def _external_interfaces() -> list[str]:
    interfaces = []
    for path in Path("/sys/class/net").iterdir():
        operstate = (path / "operstate").read_text().strip() if (path / "operstate").exists() else "down"
        if path.name != "lo" and operstate == "up":
            interfaces.append(path.name)
    return interfaces


@pytest.mark.skipif(shutil.which("tcpdump") is None or os.geteuid() != 0, reason="needs tcpdump and root")
def test_dds_traffic_never_leaves_loopback(tmp_path: Path, ros_domain: int) -> None:
    interfaces = _external_interfaces()
    if not interfaces:
        pytest.skip("no external interface is up")
    captures = []
    for iface in interfaces:
        pcap = tmp_path / f"{iface}.pcap"
        captures.append((pcap, subprocess.Popen(
            ["tcpdump", "-i", iface, "-n", "-U", "-w", str(pcap), "udp and not port 53"],
            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
        )))
    time.sleep(1.0)  # tcpdump is listening
    publisher = spawn_python(["-m", "helpers.publish_samples"], ros_domain)
    try:
        receiver = spawn_python(["-m", "helpers.receive_samples", "40"], ros_domain)
        out, _ = receiver.communicate(timeout=90)
        time.sleep(3.0)  # discovery announcements repeat: give leaks time to show
    finally:
        stop(publisher)
    assert receiver.returncode == 0, out
    for pcap, proc in captures:
        proc.terminate()
        _, err = proc.communicate(timeout=10)
        count = subprocess.run(["tcpdump", "-n", "-r", str(pcap)], capture_output=True, text=True).stdout
        assert "packets captured" in err, err
        assert count.strip() == "", f"DDS packets left the machine on {pcap.stem}:\n{count[:2000]}"
