"""The policy node over DDS on loopback: beside the bridge process (one step, a closed-loop rollout that
matches the in-process run_episode) and beside a fake driver (bad input, missing model), plus its
launch file. A step whose rollout ends while it computes is not published."""
from __future__ import annotations

import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
import rclpy
from ament_index_python.packages import get_package_share_directory
from helpers.policy_fixtures import tiny_policy
from rclpy.context import Context
from rclpy.executors import MultiThreadedExecutor, SingleThreadedExecutor
from rclpy.parameter import Parameter
from sim_bridge.closed_loop import run_episode
from sim_ros.bridge_client import BridgeHarness
from sim_ros.policy_client import FakeDriver, PolicyHarness

from fiper_msgs.msg import RolloutEvent
from fiper_ros.interface.conversions import floats_of, stamp_ns
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC
from fiper_ros.launcher.config import load_launch
from fiper_ros.nodes.policy_node import IMAGE_TOPIC_PARAMS, NODE_CLASS
from fiper_ros.platform.process import stop_executor
from fiper_ros.policy.encoder import CAMERAS
from fiper_ros.policy.session import PolicyAction, PolicyStep

ROOT = Path(os.environ["FIPER_ROOT"])
SORTING = ROOT / "models" / "sorting"
SECOND = 1_000_000_000


@dataclass
class Loop:
    """The bridge process and the policy node (with the Sorting model) in the test's domain."""

    bridge: BridgeHarness
    policy: PolicyHarness


@pytest.fixture
def loop(ros_domain: int) -> Iterator[Loop]:
    bridge = BridgeHarness(ros_domain, realtime_factor=0.0)
    policy = PolicyHarness(bridge.context, bridge.executor, model=str(SORTING))
    try:
        bridge.wait_ready()
        policy.wait_ready()
        assert bridge.spin_until(lambda: policy.node._command_pub.get_subscription_count() >= 1)
        yield Loop(bridge, policy)
    finally:
        policy.close()
        output = bridge.close()
        assert "Traceback" not in output, output


@pytest.fixture
def ros_context(ros_domain: int) -> Iterator[tuple[Context, SingleThreadedExecutor]]:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    try:
        yield context, executor
    finally:
        executor.shutdown()
        rclpy.try_shutdown(context=context)


def test_a_reset_gets_embedding_batch_and_a_command_the_bridge_executes(loop: Loop) -> None:
    bridge, policy = loop.bridge, loop.policy
    response = bridge.reset("sorting", "id", 1000)
    rid = response.rollout_id
    tick = bridge.first_tick(rid)
    embedding, batch, command = policy.wait_outputs(rid, 0)
    config = policy.node.policy.config
    b, h, d, e = config.sample_batch, config.horizon, config.action_dim, config.embed_dim
    assert (b, h, d, e, config.exec_steps) == (32, 8, 2, 128, 4)
    assert list(embedding.shape) == [e] and embedding.data.typecode == "f" and len(embedding.data) == e
    assert (batch.batch_size, batch.horizon, batch.action_dim, batch.exec_steps, batch.action_space) == \
        (b, h, d, config.exec_steps, "ee_position")
    assert len(batch.data) == b * h * d
    for msg in (embedding, batch, command):
        assert (msg.rollout_id, msg.step) == (rid, 0)
        assert stamp_ns(msg.header.stamp) == tick.stamp
    chunks = floats_of(batch.data).reshape(b, h, d)
    assert (command.num_actions, command.action_dim, command.action_space) == (config.exec_steps, d, "ee_position")
    assert command.observation_history == 0  # T_h = 1: the tick alone
    np.testing.assert_array_equal(floats_of(command.data).reshape(-1, d), chunks[0, : config.exec_steps])
    # the bridge executes the command: the next tick comes, nothing was rejected
    assert bridge.next_tick(tick.stamp).stamp > tick.stamp
    policy.wait_outputs(rid, 1)
    assert bridge.spin_until(lambda: int(bridge.client.diagnostics.get("policy_step") or 0) >= 2)
    assert not [k for k in bridge.client.diagnostics if k.startswith("rejected.")], bridge.client.diagnostics
    # the same seed in process: the same observation, the same noise, the same outputs
    episode = run_episode(policy.node.policy, "id", 1000, max_policy_steps=1)
    assert episode.rollout is not None
    np.testing.assert_array_equal(floats_of(embedding.data), episode.rollout.embeddings[0])
    np.testing.assert_array_equal(chunks, episode.rollout.actions[0])


def test_a_closed_loop_rollout_runs_until_halted(loop: Loop) -> None:
    bridge, policy = loop.bridge, loop.policy
    steps = 3
    rid = bridge.reset("sorting", "id", 1001).rollout_id
    for step in range(steps):
        policy.wait_outputs(rid, step)
    assert bridge.spin_until(lambda: int(bridge.client.diagnostics.get("policy_step") or 0) >= steps)
    assert bridge.halt().success
    assert bridge.end_of(rid).outcome == RolloutEvent.OUTCOME_FAILURE
    node = policy.node
    assert policy.spin_until(lambda: node.session.running is None)
    ended = node.session.last_ended
    assert ended is not None and ended.rollout_id == rid and ended.outcome == "failure" and ended.steps >= steps
    assert policy.spin_until(lambda: policy.probe.diagnostics.get("rollouts_seen") == "1"
                             and policy.probe.diagnostics.get("rollout_id") == "")
    diagnostics = policy.probe.diagnostics
    assert float(diagnostics["latency_p50_ms"]) > 0 and diagnostics["model"] == str(SORTING)
    assert (diagnostics["batch_size"], diagnostics["horizon"], diagnostics["action_dim"]) == ("32", "8", "2")
    assert diagnostics["level"] == "0", diagnostics
    # Nothing after the END: the next rollout's first step comes after anything of the halted one on the
    # same ordered topics (one writer each, one executor thread computing).
    following = bridge.reset("sorting", "id", 1002).rollout_id
    policy.wait_outputs(following, 0)
    for outputs in (policy.probe.embeddings, policy.probe.batches, policy.probe.commands):
        assert [m.step for m in outputs if m.rollout_id == rid] == list(range(ended.steps))
    # the ROS rollout is the in-process rollout of the same seed, step by step
    episode = run_episode(node.policy, "id", 1001, max_policy_steps=steps)
    assert episode.rollout is not None
    for step in range(steps):
        embedding, _, _ = policy.probe.outputs(rid, step)
        np.testing.assert_array_equal(floats_of(embedding.data), episode.rollout.embeddings[step])


def test_bad_input_is_rejected_and_the_node_keeps_acting(ros_context: tuple[Context, SingleThreadedExecutor],
                                                         tmp_path: Path) -> None:
    context, executor = ros_context
    model = tiny_policy().save(tmp_path / "tiny")
    policy = PolicyHarness(context, executor, model=str(model), start_wait_s=0.2)
    driver = FakeDriver(context, proprio_dim=4)
    executor.add_node(driver)
    try:
        policy.wait_ready()
        probe = policy.probe
        driver.tick(5 * SECOND)  # no rollout runs: waits for a START that never comes
        policy.wait_rejected("unknown_rollout", 1)
        rid = 77
        driver.event(rid, RolloutEvent.EVENT_START, 10 * SECOND)
        driver.tick(10 * SECOND, wrist_size=64)
        policy.wait_rejected("shape", 1)
        driver.tick(11 * SECOND, third_encoding="bgr8")
        policy.wait_rejected("encoding", 1)
        driver.tick(12 * SECOND, proprio=[0.1, 0.2, float("nan"), 0.0])
        policy.wait_rejected("non_finite", 1)
        driver.tick(13 * SECOND, proprio=[0.1, 0.2, 0.3])
        policy.wait_rejected("shape", 2)
        assert not probe.embeddings and not probe.commands
        driver.tick(14 * SECOND)  # a good tick: the first step of the rollout
        embedding, batch, _ = policy.wait_outputs(rid, 0)
        assert batch.batch_size == policy.node.policy.config.sample_batch
        driver.event(rid, RolloutEvent.EVENT_END, 15 * SECOND)
        assert policy.spin_until(lambda: policy.node.session.running is None)
        driver.tick(int(14.5 * SECOND))  # overtook the END: late, ignored
        assert policy.spin_until(lambda: probe.diagnostics.get("ticks.late") == "1"), probe.diagnostics
        assert policy.spin_until(lambda: probe.diagnostics.get("ticks.partial_dropped") == "4"), probe.diagnostics
        assert len(probe.embeddings) == 1 and probe.diagnostics["level"] == "1"  # WARN after rejections
        assert probe.diagnostics["lifecycle_state"] == "active"
    finally:
        policy.close()
        executor.remove_node(driver)
        driver.destroy_node()


def test_a_step_whose_rollout_ends_while_it_computes_is_not_published(ros_domain: int,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = MultiThreadedExecutor(num_threads=3, context=context)  # as the node's own process spins
    policy = PolicyHarness(context, executor, model=str(SORTING))
    driver = FakeDriver(context, proprio_dim=4)
    executor.add_node(driver)
    computing, release = threading.Event(), threading.Event()
    try:
        policy.wait_ready()
        node, probe, rid = policy.node, policy.probe, 5
        assert node.session is not None
        compute = node.session.compute

        def held(step: PolicyStep) -> PolicyAction:
            """The real computation, begun only once the test let it (the END is seen meanwhile, whatever
            the machine's speed)."""
            computing.set()
            assert release.wait(timeout=60)
            return compute(step)

        monkeypatch.setattr(node.session, "compute", held)
        driver.event(rid, RolloutEvent.EVENT_START, 10 * SECOND)
        driver.tick(10 * SECOND)
        assert policy.spin_until(lambda: computing.is_set() and node.session.running.steps == 1)
        driver.event(rid, RolloutEvent.EVENT_END, 11 * SECOND)  # the supervisor halted: step 0 is computing
        assert policy.spin_until(lambda: node.session.running is None)  # seen during the computation
        release.set()
        assert policy.spin_until(lambda: probe.diagnostics.get("steps_dropped_after_end") == "1" or node.published,
                                 timeout=60), probe.diagnostics
        assert probe.diagnostics["steps_dropped_after_end"] == "1"
        assert node.published == 0 and not probe.embeddings and not probe.batches and not probe.commands
    finally:
        release.set()
        stop_executor(executor)
        policy.close()
        executor.remove_node(driver)
        driver.destroy_node()
        rclpy.try_shutdown(context=context)


def test_a_missing_model_keeps_the_node_alive_until_it_appears(ros_context: tuple[Context, SingleThreadedExecutor],
                                                               tmp_path: Path) -> None:
    context, executor = ros_context
    folder = tmp_path / "later"
    policy = PolicyHarness(context, executor, model=str(folder))
    try:
        message = "lacks policy.yaml and policy.pt"
        assert policy.spin_until(lambda: message in policy.probe.diagnostics.get("message", ""))
        assert policy.probe.diagnostics["level"] == "2" and policy.node.lifecycle_state() == "unconfigured"
        tiny_policy().save(folder)
        assert policy.spin_until(lambda: policy.node.lifecycle_state() == "active")
    finally:
        policy.close()


def test_launch_file_and_parameter_defaults(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    try:
        node = NODE_CLASS(context=context, namespace="/fiper",
                          parameter_overrides=[Parameter("autostart", value=False)])
        defaults = {name: node.get_parameter(name).value for name in (
            "events_topic", "embedding_topic", "action_chunks_topic", "model", "batch")}
        assert defaults == {"events_topic": EVENTS_TOPIC, "embedding_topic": EMBEDDING_TOPIC,
                            "action_chunks_topic": ACTIONS_TOPIC,
                            "model": "models/sorting", "batch": 0}
        assert tuple(IMAGE_TOPIC_PARAMS) == CAMERAS
        node.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    # its launch file: the shipped model, required; the other values are the node's (test_parameter_defaults.py)
    (spec,) = load_launch(ROOT / "fiper_ros" / "launch" / "policy.launch.yaml", {"batch": "8"}).nodes
    assert (spec.module, spec.fqn, spec.required) == ("fiper_ros.nodes.policy_node", "/fiper/policy_node", True)
    assert Path(spec.parameters["model"]) == Path(get_package_share_directory("fiper_ros")) / "models" / "sorting"
    assert spec.parameters["batch"] == 8
