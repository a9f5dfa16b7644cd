"""``fiper record`` writes what was published (the latched rollout event too, with its offered QoS), and
``fiper snapshot`` (as the README writes it: no ``-o``) writes a bag around an alarm rise; both as separate
processes over DDS (loopback). Beside a real suite, the snapshot after a latched alarm is one bag (the heartbeats
after the END name the latched rollout, no second bag of "rollout 0"), and it replays to the suite's verdicts.
The black box's window, bounds and rise rule by hand: test_blackbox.py;
crashes: test_recordings.py."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from helpers.dds import spawn_python, stop
from helpers.stream import Policy
from helpers.suite import Suite
from helpers.synthetic import FAIL_FROM, make_rollout

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.cli import main
from fiper_ros.interface.conversions import to_stamp
from fiper_ros.interface.topics import ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC


def test_record_writes_what_was_published(tmp_path: Path, ros_domain: int, policy: Policy) -> None:
    driver = policy.driver
    driver.start(5)  # published before the recorder exists: captured through TRANSIENT_LOCAL
    bag = tmp_path / "recorded"
    proc = spawn_python(["-m", "fiper_ros.cli", "record", "-o", str(bag), "--domain", str(ros_domain)], ros_domain)
    try:
        assert policy.spin_until(lambda: min(driver.embeddings.get_subscription_count(), driver.batches.get_subscription_count(),
                                             driver.events.get_subscription_count()) >= 1, timeout=30)
        policy.spin_until(lambda: False, 0.5)
        rollout = make_rollout(300, length=10)
        for step in range(rollout.length):
            driver.step(5, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
            policy.spin_until(lambda: False, 0.02)
        driver.end(5, True)
        policy.spin_until(lambda: False, 1.0)
        assert bag.is_dir() and not (bag / "metadata.yaml").exists()  # live: there from the start, unfinished
    finally:
        output = stop(proc)
    assert proc.returncode == 0, output
    assert (bag / "metadata.yaml").is_file()
    (recorded,) = read_rollouts(bag)
    assert (recorded.rollout_id, recorded.success, recorded.task) == ("5", True, "synthetic")
    assert np.array_equal(recorded.embeddings, rollout.embeddings)
    assert np.array_equal(recorded.actions, rollout.actions)
    with BagReader(bag) as reader:
        assert reader.offered_qos(EVENTS_TOPIC)[0].durability.name == "TRANSIENT_LOCAL"
        assert reader.offered_qos(EMBEDDING_TOPIC)[0].durability.name == "VOLATILE"
        assert reader.info.source == "fiper record" and not reader.info.synthetic
        assert (reader.info.embedding_dim, reader.info.batch_size, reader.info.task) == (16, 32, "synthetic")
        assert {t for t in reader.topics} == {EVENTS_TOPIC, EMBEDDING_TOPIC, ACTIONS_TOPIC}


def test_snapshot_writes_a_bag_around_an_alarm_rise(tmp_path: Path, ros_domain: int, policy: Policy) -> None:
    driver, out, rise_step = policy.driver, tmp_path / "runs" / "snapshots", 12  # the default -o
    proc = spawn_python(["-m", "fiper_ros.cli", "snapshot", "--before", "2", "--after", "1"], ros_domain,
                        cwd=tmp_path)
    try:
        assert policy.spin_until(lambda: policy.alarm.get_subscription_count() >= 1
                                 and driver.embeddings.get_subscription_count() >= 1, timeout=30)
        policy.spin_until(lambda: False, 0.5)
        rollout = make_rollout(301)
        driver.start(6)
        for step in range(rollout.length):
            driver.step(6, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)
            state = FailureAlarm.STATE_ALARM if step >= rise_step else FailureAlarm.STATE_OK
            alarm = FailureAlarm(rollout_id=6, step=step, state=state, latched=step >= rise_step, combine="and")
            alarm.header.stamp = to_stamp(step)
            policy.alarm.publish(alarm)
            policy.spin_until(lambda: False, 0.1)
        assert policy.spin_until(lambda: out.is_dir() and any((b / "metadata.yaml").is_file() for b in out.iterdir()),
                                 timeout=10)
    finally:
        output = stop(proc)
    assert proc.returncode == 0, output
    (bag,) = [p for p in out.iterdir()]
    assert bag.name.endswith(f"_rollout6_step{rise_step}")
    with BagReader(bag) as reader:
        alarms = [(m.log_time_ns, reader.decode(m)) for m in reader.messages([ALARM_TOPIC])]
        steps = sorted(reader.decode(m).step for m in reader.messages([EMBEDDING_TOPIC]))
        times = [m.log_time_ns for m in reader.messages()]
    rise = next(t for t, a in alarms if a.state == FailureAlarm.STATE_ALARM)
    assert next(a.step for _, a in alarms if a.state == FailureAlarm.STATE_ALARM) == rise_step
    assert rise - 2e9 <= min(times) and max(times) <= rise + 1e9  # the window [rise - before, rise + after]
    # ... filled on both sides, without gaps: steps go out every 0.1 s (more under load), so four before the
    # rise and two after it lie well inside the 2 s and 1 s (the exact window: test_blackbox.py)
    assert steps == list(range(steps[0], steps[-1] + 1))
    assert steps[0] < rise_step - 3 and steps[-1] > rise_step + 1


def test_the_snapshot_after_a_latched_alarm_is_one_bag_that_replays(tmp_path: Path, ros_domain: int,
                                                                     small_calibration: Path) -> None:
    out = tmp_path / "runs" / "snapshots"
    suite = Suite(ros_domain, str(small_calibration))
    proc = spawn_python(["-m", "fiper_ros.cli", "snapshot", "--before", "10", "--after", "5"], ros_domain, cwd=tmp_path)
    try:
        suite.wait_active()
        drv = suite.driver
        assert suite.spin_until(lambda: suite.fusion._alarm_pub.get_subscription_count() >= 2
                                and drv.embeddings.get_subscription_count() >= 2
                                and drv.batches.get_subscription_count() >= 2
                                and drv.events.get_subscription_count() >= 4, timeout=30), stop(proc)
        rollout = make_rollout(330, fail=True)
        alarms = suite.run(rollout, rollout_id=31)  # ends with END; the latch holds, the heartbeats repeat it
        assert alarms[FAIL_FROM].state == FailureAlarm.STATE_ALARM
        ended = len(drv.alarms)
        # the snapshot is finished at rise + 5 s: the heartbeats of those seconds (after the END) are no rise
        assert suite.spin_until(lambda: out.is_dir() and any((b / "metadata.yaml").is_file() for b in out.iterdir()),
                                timeout=30)
        beats = [m for m in drv.alarms[ended:] if m.heartbeat]
        assert len(beats) >= 5 and all((m.rollout_id, m.state, m.latched) == (31, FailureAlarm.STATE_ALARM, True)
                                       for m in beats), beats[:3]
    finally:
        output = stop(proc)
        suite.close()
    assert proc.returncode == 0, output
    assert "1 snapshot(s) written" in output, output
    (bag,) = out.iterdir()
    assert bag.name.endswith(f"_rollout31_step{FAIL_FROM}")
    report = tmp_path / "report.json"
    assert main(["replay", str(bag), "--calibration", str(small_calibration), "--offline",
                 "--report", str(report)]) == 0
    (replayed,) = json.loads(report.read_text())["rollouts"]
    assert (replayed["rollout_id"], replayed["outcome"], replayed["first_alarm"]) == (31, "failure", FAIL_FROM)
    assert [s["state"] for s in replayed["steps"]] == [{FailureAlarm.STATE_OK: "ok", FailureAlarm.STATE_ALARM: "alarm"}[
        alarms[t].state] for t in range(rollout.length)]
