"""`fiper echo` (``--changes``, ``--brief``: on a stream by hand and on the alarm stream a live suite published) and
`fiper launch --in-process` over real DDS on loopback."""
from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import time
from pathlib import Path

import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor

import math

import pytest

from fiper_msgs.msg import FailureAlarm, Score
from fiper_ros.commands.echo import Printer, matched_line
from fiper_ros.commands.errors import UsageError
from fiper_ros.data_paths import package_share
from fiper_ros.interface import qos
from fiper_ros.platform.dds import PARENT_PID_ENV, interrupt_group
from fiper_ros.platform.process import DISCOVERY_PROFILE
from helpers.dds import ros_env, spawn_python, stop
from helpers.launch import node_entry, suite_config, write_launch
from helpers.suite import PolicySideNode, Suite
from helpers.synthetic import FAIL_FROM, make_rollout

OK, ALARMED, UNKNOWN = FailureAlarm.STATE_OK, FailureAlarm.STATE_ALARM, FailureAlarm.STATE_UNKNOWN
NAN = math.nan


def _fiper(args: list[str], domain: int, stderr: int = subprocess.STDOUT) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "fiper_ros.cli", *args], env=ros_env(domain),
                            stdout=subprocess.PIPE, stderr=stderr, text=True, start_new_session=True)


def _read_until(proc: subprocess.Popen[str], text: str, timeout: float) -> str:
    """What ``proc`` wrote to its stderr pipe until a write contained ``text`` (or ``timeout`` s passed, or it
    closed the pipe); read from the pipe's descriptor, before anything read it through its text wrapper."""
    assert proc.stderr is not None
    fd, read, deadline = proc.stderr.fileno(), b"", time.monotonic() + timeout
    while text.encode() not in read and (left := deadline - time.monotonic()) > 0:
        if not select.select([fd], [], [], left)[0] or not (chunk := os.read(fd, 4096)):
            break
        read += chunk
    return read.decode(errors="replace")


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


def _alarm(rollout_id: int, step: int, state: int, reason: str, *, heartbeat: bool = False,
           act: bool = True) -> FailureAlarm:
    """An alarm with RND-OE 2.0 against 1.5 and ACE 1.0 against 3.0 (``act`` False: ACE not judged, NaN)."""
    return FailureAlarm(rollout_id=rollout_id, step=step, state=state, latched=state == ALARMED, obs_exceeded=True,
                        act_exceeded=False, eta_obs=2.0, gamma_obs=1.5, eta_act=1.0 if act else NAN,
                        gamma_act=3.0 if act else NAN, combine="and", reason=reason, heartbeat=heartbeat,
                        detectors=["rnd_oe", "ace"], eta=[2.0, 1.0 if act else NAN],
                        gamma=[1.5, 3.0 if act else NAN], exceeded=[True, False], votes=2)


#: An alarm stream as the fusion node publishes it around one alarmed rollout, by hand.
STREAM = [
    _alarm(0, 0, UNKNOWN, "no active rollout", heartbeat=True),
    _alarm(0, 0, UNKNOWN, "no active rollout", heartbeat=True),
    _alarm(4, 0, UNKNOWN, "waiting for the first scores of the rollout", heartbeat=True),
    _alarm(4, 0, OK, "below thresholds"), _alarm(4, 0, OK, "below thresholds", heartbeat=True),
    _alarm(4, 1, OK, "below thresholds"),
    _alarm(4, 2, ALARMED, "exceeded: rnd_oe, ace (and)"), _alarm(4, 3, ALARMED, "latched since step 2"),
    _alarm(4, 3, ALARMED, "latched since step 2", heartbeat=True),  # after the END: the rollout's own heartbeat
    _alarm(5, 0, OK, "below threshold (rnd_oe alone)", act=False),
]


def test_echo_changes_and_brief_on_an_alarm_stream_by_hand() -> None:
    printer = Printer("fiper_msgs/msg/FailureAlarm", brief=True, changes=True)
    assert [line for line in map(printer.text, STREAM) if line is not None] == [
        "rollout 0 step 0: UNKNOWN (heartbeat) RND-OE 2.000>1.500 ACE 1.000<=3.000 | no active rollout",
        "rollout 4 step 0: UNKNOWN (heartbeat) RND-OE 2.000>1.500 ACE 1.000<=3.000 | waiting for the first scores of "
        "the rollout",
        "rollout 4 step 0: OK RND-OE 2.000>1.500 ACE 1.000<=3.000 | below thresholds",
        "rollout 4 step 2: ALARM latched RND-OE 2.000>1.500 ACE 1.000<=3.000 | exceeded: rnd_oe, ace (and)",
        "rollout 5 step 0: OK RND-OE 2.000>1.500 | below threshold (rnd_oe alone)"]
    every = Printer("fiper_msgs/msg/FailureAlarm", brief=True)
    assert sum(every.text(m) is not None for m in STREAM) == len(STREAM)
    changes = Printer("fiper_msgs/msg/FailureAlarm", changes=True)  # the full block, only at a change
    assert sum(changes.text(m) is not None for m in STREAM) == 5 and "reason: 'no active rollout'" in \
        Printer("fiper_msgs/msg/FailureAlarm").text(STREAM[0])


def test_echo_brief_of_scores_and_other_types() -> None:
    scores = [Score(rollout_id=4, step=s, detector="ace", score=0.5, windowed_score=w, threshold=1.25,
                    exceeded=w > 1.25, window=3, complete=s >= 2) for s, w in enumerate((0.5, 1.0, 1.5, 2.0, 1.0))]
    printer = Printer("fiper_msgs/msg/Score", brief=True, changes=True)
    assert [line for line in map(printer.text, scores) if line is not None] == [
        "rollout 4 step 0: ace score 0.500, windowed 0.500 <= 1.250 (below, window 3 (incomplete))",
        "rollout 4 step 2: ace score 0.500, windowed 1.500 > 1.250 (exceeded, window 3)",
        "rollout 4 step 4: ace score 0.500, windowed 1.000 <= 1.250 (below, window 3)"]
    with pytest.raises(UsageError, match="--brief formats fiper_msgs/msg/FailureAlarm and fiper_msgs/msg/Score, not "
                                         "std_msgs/msg/String"):
        Printer("std_msgs/msg/String", brief=True)
    from std_msgs.msg import String

    strings = Printer("std_msgs/msg/String", changes=True)
    assert [strings.text(String(data=d)) for d in ("a", "a", "b")] == ["data: 'a'\n---", None, "data: 'b'\n---"]


def test_echo_changes_on_the_alarm_stream_of_a_live_suite(suite: Suite, ros_domain: int) -> None:
    """``fiper echo /fiper/alarm --changes --brief`` beside a suite running a failing rollout and its heartbeats
    after the END: one line per change of the stream the test's driver recorded (every message), the first ALARM
    once, none of the latched steps and heartbeats that repeat it."""
    echo = _fiper(["echo", "/fiper/alarm", "--changes", "--brief", "--wait", "30"], ros_domain,
                  stderr=subprocess.PIPE)
    drv = suite.driver
    try:
        # both ends matched: the alarm publisher counts the echo's reader, the reader has matched the publisher
        # (a sample the publisher sends before the reader matched it is lost beyond the latched latest)
        assert suite.spin_until(lambda: suite.fusion._alarm_pub.get_subscription_count() >= 2, 30)
        said = _read_until(echo, matched_line("/fiper/alarm", "fiper_msgs/msg/FailureAlarm", 1), 30)
        assert matched_line("/fiper/alarm", "fiper_msgs/msg/FailureAlarm", 1) in said, said
        suite.run(make_rollout(320, fail=True), rollout_id=21)  # ends with END
        ended = len(drv.alarms)
        assert suite.spin_until(lambda: sum(m.heartbeat for m in drv.alarms[ended:]) >= 3, 10)
    finally:
        out = stop(echo)
    lines = [line for line in out.splitlines() if line.startswith("rollout 21 ")]
    printer = Printer("fiper_msgs/msg/FailureAlarm", brief=True, changes=True)
    recorded = [line for line in map(printer.text, [m for m in drv.alarms if m.rollout_id == 21]) if line is not None]
    assert lines == recorded, out
    assert [line.split(": ")[1].split()[0] for line in lines][-2:] == ["OK", "ALARM"]
    assert lines[-1].startswith(f"rollout 21 step {FAIL_FROM}: ALARM latched RND-OE ")
    repeats = [m for m in drv.alarms if m.rollout_id == 21 and m.state == ALARMED]
    assert len(repeats) > len(make_rollout(320).embeddings) - FAIL_FROM  # latched steps and heartbeats, left out


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
    driver = PolicySideNode(context)
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
        interrupt_group(launch.pid)
        out = launch.communicate(timeout=30)[0]
    assert launch.returncode == 0, out
    assert out.count("running in-process") == 3
    assert f"[launch] DDS discovery: Fast DDS profile {package_share() / DISCOVERY_PROFILE}" in out, out


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
