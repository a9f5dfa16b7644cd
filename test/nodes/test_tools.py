"""`fiper echo` and `fiper launch --in-process` over real DDS on loopback."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

from fiper_msgs.msg import FailureAlarm
from fiper_ros.dds import PARENT_PID_ENV
from fiper_ros.interface import qos
from helpers.dds import ros_env, spawn_python
from helpers.launch import node_entry, suite_config, write_launch
from helpers.suite import Driver


def _fiper(args: list[str], domain: int) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "fiper_ros.cli", *args], env=ros_env(domain),  # noqa: S603
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)


def test_echo_prints_a_latched_alarm_published_before_it_started(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    node = rclpy.create_node("alarm_source", context=context)
    publisher = node.create_publisher(FailureAlarm, "/fiper/alarm", qos.ALARM)
    publisher.publish(FailureAlarm(rollout_id=42, step=7, state=FailureAlarm.STATE_ALARM, latched=True,
                                   reason="both exceeded"))
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    echo = _fiper(["echo", "/fiper/alarm", "--count", "1", "--wait", "30"], ros_domain)
    try:
        deadline = time.monotonic() + 60
        while echo.poll() is None and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        out = echo.communicate(timeout=10)[0]
    finally:
        if echo.poll() is None:
            os.killpg(echo.pid, signal.SIGKILL)
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert echo.returncode == 0, out
    assert "rollout_id: 42" in out and "step: 7" in out and "state: 1" in out and "reason: 'both exceeded'" in out


def test_echo_of_a_missing_topic_says_so(ros_domain: int) -> None:
    out, _ = _fiper(["echo", "/fiper/nothing_here", "--wait", "1"], ros_domain).communicate(timeout=60)
    assert "not found" in out and "Traceback" not in out


def test_launch_in_process_runs_the_suite_and_stops_on_ctrl_c(tmp_path: Path, calibration_dir: Path,
                                                             ros_domain: int) -> None:
    scoring = {"calibration_dir": str(calibration_dir)}
    config = write_launch(tmp_path / "suite.launch.yaml", node_entry("rnd_oe_node", scoring),
                          node_entry("ace_node", scoring), node_entry("fusion_node"))
    launch = _fiper(["launch", str(config), "--in-process"], ros_domain)
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    driver = Driver(context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(driver)
    try:
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and not (driver.embeddings.get_subscription_count()
                                                   and driver.batches.get_subscription_count()
                                                   and any("no active rollout" in m.reason for m in driver.alarms)):
            executor.spin_once(timeout_sec=0.05)
        assert driver.embeddings.get_subscription_count() == 1 and driver.batches.get_subscription_count() == 1
        assert any(m.state == FailureAlarm.STATE_UNKNOWN for m in driver.alarms)
    finally:
        executor.shutdown()
        driver.destroy_node()
        rclpy.try_shutdown(context=context)
        os.killpg(launch.pid, signal.SIGINT)
        out = launch.communicate(timeout=30)[0]
    assert launch.returncode == 0, out
    assert out.count("running in-process") == 3


def _gone(pid: int) -> bool:
    """``pid`` has exited (a zombie nobody reaped counts: it holds no DDS participant)."""
    try:
        return Path(f"/proc/{pid}/status").read_text().split("State:")[1].split()[0] in ("Z", "X")
    except (FileNotFoundError, IndexError):
        return True


def test_a_launcher_and_its_nodes_end_with_the_process_that_started_it(tmp_path: Path, calibration_dir: Path,
                                                                     ros_domain: int) -> None:
    # A test run or a `fiper demo` killed with SIGKILL left its `fiper launch` running (its parent gone), and
    # the suite kept speaking in the run's domain: FIPER_PARENT_PID now ends the launcher with its parent.
    config = suite_config(tmp_path / "suite.yaml", calibration_dir)
    starter = spawn_python(["-c", "import os, subprocess, sys, time\n"
                            f"subprocess.Popen([sys.executable, '-m', 'fiper_ros.cli', 'launch', {str(config)!r}],"
                            f" env=os.environ | {{{PARENT_PID_ENV!r}: str(os.getpid())}})\n"
                            "time.sleep(600)\n"], ros_domain)
    assert starter.stdout is not None
    pids: list[int] = []
    for line in starter.stdout:
        if line.startswith("[launch] started "):
            pids.append(int(line.split("(pid ")[1].split(")")[0]))
        if len(pids) == 4:
            break
    launcher = next(int(p) for p in Path(f"/proc/{starter.pid}/task/{starter.pid}/children").read_text().split())
    starter.kill()
    starter.wait()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not all(_gone(pid) for pid in (launcher, *pids)):
        time.sleep(0.1)
    assert [pid for pid in (launcher, *pids) if not _gone(pid)] == []
