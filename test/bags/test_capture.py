"""``fiper record`` writes what was published (the latched rollout event too, with its offered QoS), and
``fiper snapshot`` writes a bag around an alarm rise; both as separate processes over DDS (loopback). The
snapshot's window itself, by hand, on the black box alone."""
from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.serialization import serialize_message

from fiper_msgs.msg import FailureAlarm
from fiper_ros.bags.reader import BagReader
from fiper_ros.bags.rollouts import read_rollouts
from fiper_ros.bags.schema import ACTIONS, ALARM, EMBEDDING, EVENTS, TOPICS, normalize_cdr
from fiper_ros.bags.snapshot import BlackBox
from fiper_ros.nodes import qos
from fiper_ros.nodes.conversions import to_stamp
from helpers.dds import spawn_python, stop
from helpers.suite import Driver
from helpers.synthetic import make_rollout

ALARM_TYPE = TOPICS[ALARM].msgtype


class Policy:
    """The test's publisher side: the suite-harness Driver plus a FailureAlarm publisher."""

    def __init__(self, domain: int) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.driver = Driver(self.context)
        self.alarm = self.driver.create_publisher(FailureAlarm, "alarm", qos.ALARM)
        self.executor.add_node(self.driver)

    def spin_until(self, condition: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and not condition():
            self.executor.spin_once(timeout_sec=0.02)
        return condition()

    def close(self) -> None:
        self.executor.shutdown()
        self.driver.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def policy(ros_domain: int) -> Iterator[Policy]:
    p = Policy(ros_domain)
    try:
        yield p
    finally:
        p.close()


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
        assert not bag.exists()  # appears only when complete
    finally:
        output = stop(proc)
    assert proc.returncode == 0, output
    (recorded,) = read_rollouts(bag)
    assert (recorded.rollout_id, recorded.success, recorded.task) == ("5", True, "synthetic")
    assert np.array_equal(recorded.embeddings, rollout.embeddings)
    assert np.array_equal(recorded.actions, rollout.actions)
    with BagReader(bag) as reader:
        assert reader.offered_qos(EVENTS)[0].durability.name == "TRANSIENT_LOCAL"
        assert reader.offered_qos(EMBEDDING)[0].durability.name == "VOLATILE"
        assert reader.info.source == "fiper record" and not reader.info.synthetic
        assert (reader.info.embedding_dim, reader.info.batch_size, reader.info.task) == (16, 32, "synthetic")
        assert {t for t in reader.topics} == {EVENTS, EMBEDDING, ACTIONS}


def test_snapshot_writes_a_bag_around_an_alarm_rise(tmp_path: Path, ros_domain: int, policy: Policy) -> None:
    driver, out, rise_step = policy.driver, tmp_path / "snapshots", 12
    proc = spawn_python(["-m", "fiper_ros.cli", "snapshot", "-o", str(out), "--before", "2", "--after", "1",
                         "--domain", str(ros_domain)], ros_domain)
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
        assert policy.spin_until(lambda: out.is_dir() and any(out.iterdir()), timeout=10)
    finally:
        output = stop(proc)
    assert proc.returncode == 0, output
    (bag,) = [p for p in out.iterdir()]
    assert bag.name.endswith(f"_rollout6_step{rise_step}")
    with BagReader(bag) as reader:
        alarms = [(m.log_time_ns, reader.decode(m)) for m in reader.messages([ALARM])]
        steps = sorted(reader.decode(m).step for m in reader.messages([EMBEDDING]))
        times = [m.log_time_ns for m in reader.messages()]
    rise = next(t for t, a in alarms if a.state == FailureAlarm.STATE_ALARM)
    assert next(a.step for _, a in alarms if a.state == FailureAlarm.STATE_ALARM) == rise_step
    assert rise - 2e9 <= min(times) and max(times) <= rise + 1e9  # the window [rise - before, rise + after]
    # ... filled on both sides, without gaps: steps go out every 0.1 s (more under load), so four before the
    # rise and two after it lie well inside the 2 s and 1 s (BlackBox's exact window: the test below)
    assert steps == list(range(steps[0], steps[-1] + 1))
    assert steps[0] < rise_step - 3 and steps[-1] > rise_step + 1


def _alarm_cdr(step: int, state: int) -> bytes:
    return normalize_cdr(serialize_message(FailureAlarm(rollout_id=6, step=step, state=state)), ALARM_TYPE)


def test_black_box_window_by_hand() -> None:
    box = BlackBox(before_s=2.0, after_s=1.0)
    s, ok, alarm = 1_000_000_000, FailureAlarm.STATE_OK, FailureAlarm.STATE_ALARM
    box.add(ALARM, ALARM_TYPE, 0, _alarm_cdr(0, alarm))  # the first alarm only sets the state: no rise
    for t in range(1, 10):  # one message a second; the rise at 5 s
        box.add(ALARM, ALARM_TYPE, t * s, _alarm_cdr(t, alarm if t >= 5 else ok))
    (rise,) = box.pending
    assert (rise.time_ns, rise.rollout_id, rise.step) == (5 * s, 6, 5)
    assert [m[0] // s for m in box.buffer] == [3, 4, 5, 6, 7, 8, 9]  # kept from rise - before while it is pending
    # [5 - 2, 5 + 1] s: the messages of 3, 4, 5 and 6 s (the bounds included)
    assert [m[0] // s for m in box.window(rise)] == [3, 4, 5, 6]
    assert box.due(6 * s - 1) == [] and box.due(6 * s) == [rise]  # due once rise + after has passed
    box.add(ALARM, ALARM_TYPE, 10 * s, _alarm_cdr(10, alarm))
    assert [m[0] // s for m in box.buffer] == [8, 9, 10] and not box.pending  # only `before` left; no new rise
