"""The suite as separate OS processes (``fiper launch``) over real DDS on loopback: the alarm at the
known step, a late-joining supervisor still gets the latched alarm, a killed scoring node turns the
state UNKNOWN within the deadline, and Ctrl-C stops everything that runs on."""
from __future__ import annotations

import os
import signal
from pathlib import Path

from rclpy.node import Node

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface import qos
from helpers.launch import Launch, node_entry, write_launch
from helpers.suite import PolicySideSession
from helpers.synthetic import FAIL_FROM, make_rollout

DEADLINE_S = 1.0
HEARTBEAT_S = 0.5
POLICY_PERIOD_S = 0.1


def test_processes_alarm_latch_for_late_joiners_and_dead_node_detection(
    tmp_path: Path, calibration_dir: Path, ros_domain: int
) -> None:
    scoring = {"calibration_dir": str(calibration_dir)}
    config = write_launch(tmp_path / "suite.launch.yaml", node_entry("rnd_oe_node", scoring),
                          node_entry("ace_node", scoring),
                          node_entry("fusion_node", {"deadline_s": DEADLINE_S, "heartbeat_s": HEARTBEAT_S}))
    launch = Launch(config, ros_domain)
    session = PolicySideSession(ros_domain)
    driver, spin_until = session.driver, session.spin_until
    try:
        assert spin_until(session.wired, timeout=60), "\n".join(launch.lines)
        assert spin_until(lambda: any("waiting" in m.reason or "no active" in m.reason for m in driver.alarms))

        # 1. a scripted failure raises ALARM exactly at the step where both windowed scores cross.
        states = session.run(make_rollout(500, fail=True), 1, lambda: launch.lines)
        first = min(s for s, m in states.items() if m.state == FailureAlarm.STATE_ALARM)
        assert first == FAIL_FROM
        assert all(states[s].state == FailureAlarm.STATE_OK for s in range(FAIL_FROM))

        # 2. a supervisor that joins now still receives the latched ALARM (transient local).
        late: list[FailureAlarm] = []
        supervisor = Node("late_supervisor", context=session.context)
        supervisor.create_subscription(FailureAlarm, "/fiper/alarm", late.append, qos.ALARM)
        session.executor.add_node(supervisor)
        assert spin_until(lambda: bool(late), timeout=10)
        assert late[0].state == FailureAlarm.STATE_ALARM and late[0].latched and late[0].rollout_id == 1

        # 3. a new rollout runs OK at 10 Hz; killing the ACE process turns the state UNKNOWN within the
        # period-based deadline (deadline_periods = 2.5 measured policy periods).
        ok_rollout = make_rollout(501)
        driver.start(2)
        for step in range(4):
            driver.step(2, step, ok_rollout.embeddings[step], ok_rollout.actions[step], ok_rollout.exec_steps)
            assert spin_until(lambda s=step: s in driver.alarms_of(2), timeout=10)
            spin_until(lambda: False, timeout=POLICY_PERIOD_S)  # pacing: a 10 Hz policy
        assert all(m.state == FailureAlarm.STATE_OK for m in driver.alarms_of(2).values())
        driver.alarms.clear()
        os.kill(launch.pid_of("ace_node"), signal.SIGKILL)
        assert spin_until(lambda: any(m.state == FailureAlarm.STATE_UNKNOWN and m.rollout_id == 2 and "ace" in m.reason
                                      for m in driver.alarms), timeout=30)
        # Within the deadline, counted in the fusion node's own heartbeats (its clock, so load stretches both
        # alike): during a rollout it repeats OK once per measured period until 2.5 periods have passed, then
        # says UNKNOWN. (test/nodes/test_faults.py counts the policy steps a kill goes unnoticed.)
        first_unknown = next(i for i, m in enumerate(driver.alarms) if m.state == FailureAlarm.STATE_UNKNOWN)
        ok_repeats = [m for m in driver.alarms[:first_unknown] if m.state == FailureAlarm.STATE_OK and m.heartbeat]
        assert len(ok_repeats) <= 3, driver.alarms[:first_unknown]
        # heartbeats go on (three more come): none of them may say OK again
        assert spin_until(lambda: len(driver.alarms) >= first_unknown + 4, timeout=10)
        assert all(m.state != FailureAlarm.STATE_OK for m in driver.alarms[first_unknown:])
        assert spin_until(lambda: any("ace_node exited with code -9" in line for line in launch.lines), timeout=5)
    finally:
        session.close()
        status = launch.interrupt()
    # Ctrl-C stopped the remaining nodes (Launch.stopped: cleanly, or by the teardown watchdog where the upstream
    # race after the killed peer hung a teardown); the launcher reports the node that died.
    assert status == 1, "\n".join(launch.lines)
    assert launch.stopped("rnd_oe_node") and launch.stopped("fusion_node"), "\n".join(launch.lines[-40:])
