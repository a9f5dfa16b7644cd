"""``fiper_ros.publishing.FiperPublisher``, the policy authors' API (issue #25), over DDS on loopback: what START, a
step and END put on the wire (the contract's QoS, one stamp and step for embedding and batch, fresh rollout ids),
what it refuses, what ``wait_for_suite`` says when nothing matched, and that it waits for ``fiper record`` (which
reports its matches on /diagnostics) so that a recording starting with the policy holds every step."""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import rclpy
from helpers.dds import spawn_python, stop
from helpers.spin import spin_until
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy

from fiper_msgs.msg import ActionChunkBatch, ObservationEmbedding, RolloutEvent, StepSignals
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import floats_of, stamp_ns
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, STEP_SIGNALS_TOPIC
from fiper_ros.publishing import FiperPublisher, SuiteNotReady


class Ends:
    """A policy node with a FiperPublisher and, in the same context, a listener of its three topics."""

    def __init__(self, domain: int, **options: object) -> None:
        self.context = Context()
        rclpy.init(context=self.context, domain_id=domain)
        self.node = Node("test_policy", context=self.context)
        self.fiper = FiperPublisher(self.node, **options)  # type: ignore[arg-type]
        self.listener = Node("test_listener", context=self.context)
        self.received: dict[str, list[object]] = {EMBEDDING_TOPIC: [], ACTIONS_TOPIC: [], EVENTS_TOPIC: [],
                                                  STEP_SIGNALS_TOPIC: []}
        for kind, topic, profile in ((ObservationEmbedding, EMBEDDING_TOPIC, qos.INPUT),
                                     (ActionChunkBatch, ACTIONS_TOPIC, qos.INPUT), (RolloutEvent, EVENTS_TOPIC,
                                                                                    qos.EVENT),
                                     (StepSignals, STEP_SIGNALS_TOPIC, qos.INPUT)):
            self.listener.create_subscription(kind, topic, self.received[topic].append, profile)
        self.executor = SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.listener)

    def matched(self) -> bool:
        publishers = [p for p in (self.fiper.embeddings, self.fiper.batches, self.fiper.events, self.fiper.signals)
                      if p is not None]
        topics = {p.topic_name for p in publishers}
        return all(p.get_subscription_count() >= 1 for p in publishers) and all(
            s.get_publisher_count() >= 1 for s in self.listener.subscriptions if s.topic_name in topics)

    def spin_until(self, condition: object, timeout: float = 10.0) -> bool:
        return spin_until(self.executor, condition, timeout)  # type: ignore[arg-type]

    def close(self) -> None:
        self.executor.shutdown()
        self.listener.destroy_node()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def ends(ros_domain: int) -> Iterator[Ends]:
    e = Ends(ros_domain, action_space="ee_position", exec_steps=4)
    try:
        assert e.spin_until(e.matched, 30)
        yield e
    finally:
        e.close()


def test_start_steps_and_end_on_the_wire(ends: Ends) -> None:
    fiper = ends.fiper
    assert fiper.embeddings.qos_profile.durability == DurabilityPolicy.VOLATILE
    assert fiper.events.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL
    first = fiper.start(task="my_task", scenario="id", max_steps=3)
    embedding = np.arange(6, dtype=np.float32).reshape(2, 3)
    chunks = np.arange(2 * 4 * 3, dtype=np.float32).reshape(2, 4, 3)
    assert [fiper.step(embedding, chunks), fiper.step(embedding, chunks + 1)] == [0, 1]
    fiper.end(success=False)
    assert fiper.rollout_id is None
    assert fiper.start(7) == 7
    assert fiper.step(embedding, chunks, stamp_ns=123) == 0
    fiper.end(success=None)
    assert ends.spin_until(lambda: len(ends.received[EVENTS_TOPIC]) == 4 and len(ends.received[ACTIONS_TOPIC]) == 3)
    events = [(e.rollout_id, e.event, e.outcome, e.task, e.scenario, e.max_steps) for e in ends.received[EVENTS_TOPIC]]
    assert events == [(first, RolloutEvent.EVENT_START, RolloutEvent.OUTCOME_UNKNOWN, "my_task", "id", 3),
                      (first, RolloutEvent.EVENT_END, RolloutEvent.OUTCOME_FAILURE, "", "", 0),
                      (7, RolloutEvent.EVENT_START, RolloutEvent.OUTCOME_UNKNOWN, "", "", 0),
                      (7, RolloutEvent.EVENT_END, RolloutEvent.OUTCOME_UNKNOWN, "", "", 0)]
    assert first > 1_600_000_000_000  # from the wall clock in ms: never an id of an earlier run
    embeddings, batches = ends.received[EMBEDDING_TOPIC], ends.received[ACTIONS_TOPIC]
    assert [(m.rollout_id, m.step) for m in embeddings] == [(b.rollout_id, b.step) for b in batches] == \
        [(first, 0), (first, 1), (7, 0)]
    assert [stamp_ns(m.header.stamp) for m in embeddings] == [stamp_ns(b.header.stamp) for b in batches]
    assert stamp_ns(embeddings[2].header.stamp) == 123 and stamp_ns(embeddings[0].header.stamp) > 0
    assert list(embeddings[0].shape) == [2, 3] and floats_of(embeddings[0].data).tolist() == list(range(6))
    batch = batches[1]
    assert (batch.batch_size, batch.horizon, batch.action_dim, batch.exec_steps, batch.action_space) == \
        (2, 4, 3, 4, "ee_position")
    assert floats_of(batch.data).tolist() == list(range(1, 25))


def test_a_steps_signals_go_out_with_its_rollout_step_and_stamp_and_only_when_given(ends: Ends) -> None:
    fiper = ends.fiper
    assert fiper.signals.qos_profile.durability == DurabilityPolicy.VOLATILE
    rollout_id = fiper.start()
    embedding, chunks = np.zeros(3), np.zeros((2, 4, 3))
    fiper.step(embedding, chunks)  # no signals: no StepSignals message
    fiper.step(embedding, chunks, signals={"chunk_mse": 0.25, "eef_z": np.float32(-1.5)}, stamp_ns=5_000_000_007)
    fiper.step(embedding, chunks, signals={})
    fiper.end(success=True)
    assert ends.spin_until(lambda: len(ends.received[ACTIONS_TOPIC]) == 3 and len(ends.received[EVENTS_TOPIC]) == 2)
    assert ends.spin_until(lambda: len(ends.received[STEP_SIGNALS_TOPIC]) >= 1, 2.0)
    (signals,) = ends.received[STEP_SIGNALS_TOPIC]
    assert (signals.rollout_id, signals.step, stamp_ns(signals.header.stamp)) == (rollout_id, 1, 5_000_000_007)
    assert stamp_ns(ends.received[EMBEDDING_TOPIC][1].header.stamp) == 5_000_000_007
    assert list(signals.names) == ["chunk_mse", "eef_z"] and list(signals.values) == [0.25, -1.5]


@pytest.mark.parametrize(("signals", "message"), [
    ({"Chunk": 1.0}, r"signals: signal name 'Chunk' must match \^\[a-z\]\[a-z0-9_\]\*\$"),
    ({"jerk": float("nan")}, "signal 'jerk' is nan: signals must be finite"),
    ({"jerk": np.inf}, "signal 'jerk' is inf: signals must be finite"),
    ({"jerk": "high"}, "signal 'jerk' is not a number: 'high'"),
])
def test_bad_signals_are_refused_before_anything_is_published(ends: Ends, signals: dict, message: str) -> None:
    fiper = ends.fiper
    fiper.start(9)
    with pytest.raises(ValueError, match=message):
        fiper.step(np.zeros(3), np.zeros((2, 4, 3)), signals=signals)
    assert fiper.next_step == 0
    fiper.step(np.ones(3), np.zeros((2, 4, 3)))
    assert ends.spin_until(lambda: len(ends.received[EMBEDDING_TOPIC]) == 1)
    assert ends.received[EMBEDDING_TOPIC][0].data[0] == 1.0  # the refused step's embedding never went out


def test_what_the_publisher_refuses(ends: Ends) -> None:
    fiper, embedding, chunks = ends.fiper, np.zeros(3), np.zeros((2, 4, 3))
    with pytest.raises(RuntimeError, match="no rollout is running: call start"):
        fiper.step(embedding, chunks)
    with pytest.raises(ValueError, match="0 means no rollout"):
        fiper.start(0)
    fiper.start(5)
    with pytest.raises(ValueError, match=r"chunks must be \[B, H, D\].*got shape \(4, 3\)"):
        fiper.step(embedding, chunks[0])
    with pytest.raises(ValueError, match="chunks are required"):
        fiper.step(embedding)
    with pytest.raises(ValueError, match="the embedding is empty"):
        fiper.step(np.zeros(0), chunks)
    with pytest.raises(ValueError, match="give the step of rollout 6"):
        fiper.step(embedding, chunks, rollout_id=6)
    assert fiper.step(embedding, chunks, rollout_id=6, step=3) == 3  # another rollout, by id and step (policy_node)
    assert fiper.next_step == 0  # the running rollout's count is its own
    with pytest.raises(ValueError, match="action_space must be one of ee_position, joint_position, joint_velocity"):
        fiper.set_layout("cartesian", 1)
    with pytest.raises(ValueError, match="exec_steps must be >= 1"):
        fiper.set_layout("ee_position", 0)


def test_observation_only_and_without_events(ros_domain: int) -> None:
    ends = Ends(ros_domain, actions_topic=None, events_topic=None, signals_topic=None)
    try:
        fiper = ends.fiper
        assert fiper.batches is None and fiper.events is None and fiper.signals is None
        with pytest.raises(ValueError, match="publishes no signals"):
            fiper.step(np.zeros(3), rollout_id=3, step=0, signals={"a": 1.0})
        with pytest.raises(RuntimeError, match="publishes no rollout events"):
            fiper.start()
        with pytest.raises(ValueError, match="publishes no action batches"):
            fiper.step(np.zeros(3), np.zeros((2, 4, 3)), rollout_id=3, step=0)
        assert ends.spin_until(ends.matched, 30)
        fiper.step(np.ones(3), rollout_id=3, step=0)
        assert ends.spin_until(lambda: len(ends.received[EMBEDDING_TOPIC]) == 1)
        assert ends.received[ACTIONS_TOPIC] == []
    finally:
        ends.close()


def test_without_a_suite_the_wait_says_what_is_missing(ends: Ends) -> None:
    with pytest.raises(SuiteNotReady) as error:
        ends.fiper.wait_for_suite(0.5)
    text = str(error.value)
    assert text.startswith(f"the FIPER suite is not ready after 0.5 s in ROS domain {ends.context.get_domain_id()}")
    assert f"an active node of the suite subscribing to {EMBEDDING_TOPIC} (none reports one on /diagnostics)" in text
    assert f"an active node of the suite subscribing to {ACTIONS_TOPIC}" in text
    assert "the fusion node (no publisher of /fiper/alarm)" in text
    assert "fiper launch fiper_ros/launch/fiper.launch.yaml calibration_dir:=DIR" in text
    with pytest.raises(SuiteNotReady, match="/fiper_record is not ready after 0.1 s .*waiting for: /fiper_record to "
                                            "report its matches on /diagnostics"):
        ends.fiper.wait_for_suite(0.1, also=["/fiper_record"], suite=False)
    assert ends.node.executor is None  # the wait spun the node in an executor of its own, and let it go


def test_a_recording_started_with_the_policy_holds_every_step(tmp_path: Path, ros_domain: int, ends: Ends) -> None:
    bag = tmp_path / "recorded"
    recorder = spawn_python(["-m", "fiper_ros.cli", "record", "-o", str(bag)], ros_domain)
    fiper = ends.fiper
    try:
        fiper.wait_for_suite(60, also=["/fiper_record"], suite=False)
        # the recorder has matched every input, but it is no node of the suite (the walkthrough's first run took it
        # for one and published before the scoring nodes were active: their first steps were lost)
        assert fiper.missing(also=["/fiper_record"]) == [
            f"an active node of the suite subscribing to {EMBEDDING_TOPIC} (none reports one on /diagnostics)",
            f"an active node of the suite subscribing to {ACTIONS_TOPIC} (none reports one on /diagnostics)",
            "the fusion node (no publisher of /fiper/alarm)"]
        rollout_id = fiper.start(task="my_task")
        chunks = np.zeros((2, 4, 3))
        for t in range(5):
            fiper.step(np.full(3, t), chunks, signals={"chunk_mse": t / 4, "step_sq": t * t})
        fiper.end(success=True)
        assert fiper.flush(30)
    finally:
        output = stop(recorder)
    assert recorder.returncode == 0, output
    (recorded,) = read_rollouts(bag)
    assert (recorded.rollout_id, recorded.success, recorded.length) == (str(rollout_id), True, 5)
    assert recorded.embeddings[:, 0].tolist() == [0, 1, 2, 3, 4]
    assert {name: values.tolist() for name, values in recorded.signals.items()} == {
        "chunk_mse": [0, 0.25, 0.5, 0.75, 1.0], "step_sq": [0, 1, 4, 9, 16]}


def test_a_reader_of_the_alarm_that_reports_must_have_matched_the_fusion_node(ends: Ends) -> None:
    """``fiper launch --summary`` (and ``fiper record``) report their alarm subscription's matches: a policy waits
    until they have matched the fusion node's KEEP_LAST(1) publisher, else the first verdicts are lost to them
    (the walkthrough's summary missed the first steps of its first rollout)."""
    from fiper_msgs.msg import FailureAlarm

    alarm = ends.listener.create_publisher(FailureAlarm, "/fiper/alarm", qos.ALARM_PUB)
    assert ends.spin_until(lambda: ends.node.count_publishers("/fiper/alarm") == 1)
    summary = "/fiper_launch_summary"
    # what its /diagnostics said (the report's keys as client.capture.report_matches writes them)
    ends.fiper._reports[summary] = {"matched_publishers./fiper/alarm": "0"}
    assert f"{summary} to match 1 publishers of /fiper/alarm (has 0)" in ends.fiper.missing(suite=False)
    ends.fiper._reports[summary] = {"matched_publishers./fiper/alarm": "1"}
    assert ends.fiper.missing(suite=False) == []
    ends.listener.destroy_publisher(alarm)
