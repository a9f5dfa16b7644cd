"""Property-based fuzzing of every message the policy node and the sim bridge node take (issue #18).

As ``test/nodes/test_fuzz.py`` does for the FIPER nodes (``test/helpers/fuzz.py`` says how): the real node
classes in a private rclpy context, their subscription (and service) callbacks called directly with generated
messages. The policy node gets camera images (any encoding, size, row step and byte count), proprioception
(NaN, huge, wrong length) and rollout events; the bridge gets action commands (any rollout, step, shape, action
space, values, observation history) between resets (any task, scenario and seed), halts and its step timer.
After every message nothing raised, every rejection is counted under a reason of
:data:`fiper_ros.runtime.validation.REASONS`, the buffers stay within their bounds and nothing is acted on that
came from a rejected part; afterwards the node acts on a valid rollout exactly as its ROS-free logic (the
policy node: :class:`~fiper_ros.policy.session.PolicySession`) or the simulation itself (the bridge: a shadow
``make_env`` of the same seed) does.
"""
from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, note
from hypothesis import strategies as st
from rclpy.context import Context
from sensor_msgs.msg import Image, JointState
from std_srvs.srv import Trigger

from fiper_msgs.msg import ActionCommand, RolloutEvent
from fiper_msgs.srv import ResetRollout
from fiper_ros.interface.conversions import float_array, rollout_event_msg, stamp_ns, to_stamp
from fiper_ros.nodes.policy_node import PolicyNode
from fiper_ros.policy.encoder import RAW_IMAGE_SIZE
from fiper_ros.policy.policy import Policy
from fiper_ros.policy.session import PolicySession
from fiper_ros.runtime.validation import DEFAULT_MAX_ABS_VALUE, REASONS, InputRejected
from helpers.fuzz import (MOSTLY, NODE_KWARGS, STAMP, TEXT, UINT8, UINT32, UINT64, bring_up, callbacks, draw_payload,
                          fuzz, load_once, node_params, private_context, record)
from helpers.policy_fixtures import random_observation, tiny_policy
from sim_bridge.bridge_node import BridgeNode
from sim_bridge.bridge_session import ACTION_SPACES, BridgeSession
from sim_bridge.env import make_env
from sim_bridge.scenarios import ScenarioError, get_scenario

#: The valid rollout after each example: an id the fuzz never uses, stamped after every stamp it uses (a tick of
#: the fuzz still waiting for its START is not acted on in the valid rollout).
VALID_ID = 2**40 + 7
VALID_STAMP = 2_000_000_000 * 1_000_000_000 + 123
ROLLOUT_IDS = st.one_of(st.sampled_from([1, 2, 3]), UINT64).map(lambda r: r + 1 if r == VALID_ID else r)
SIDE = RAW_IMAGE_SIZE
WRIST, THIRD = "/camera/wrist/image_raw", "/camera/third/image_raw"
IMAGE_TOPICS = {"wrist_rgb": WRIST, "third_rgb": THIRD}


@pytest.fixture
def context(ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> Iterator[Context]:
    """A private rclpy context; the policy node loads its policy once per test (``load_once``)."""
    load_once(monkeypatch, Policy, "load")
    with private_context(ros_domain) as ctx:
        yield ctx


@pytest.fixture(scope="module")
def model(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return tiny_policy().save(tmp_path_factory.mktemp("policy") / "tiny")


# the policy node ---------------------------------------------------------------------------------------
_ENCODING = st.one_of(st.just("rgb8"), st.sampled_from(["bgr8", "mono8", "rgba8", "RGB8", ""]), TEXT)
_SIDE = st.one_of(st.just(SIDE), st.sampled_from([0, 1, SIDE - 1, SIDE + 1, 64]), UINT32)
_PAD = st.one_of(st.just(0), st.integers(1, 5), st.integers(-3 * SIDE, -1))
_BYTES = st.sampled_from(["exact", "exact", "exact", "short", "long", "empty"])
POLICY_INPUTS = st.sampled_from(["tick", "tick", "tick", "image", "proprio", "event", "event", "diagnostics"])


def draw_image(draw: st.DrawFn, stamp: int, seed: int) -> tuple[Image, bool]:
    """An Image (random pixels) and whether it is what the policy takes: rgb8, 96 x 96, rows of at least 288
    bytes (a padding is fine) and height x step bytes."""
    valid = draw(MOSTLY)
    height, width = (SIDE, SIDE) if valid else (draw(_SIDE), draw(_SIDE))
    encoding = "rgb8" if valid else draw(_ENCODING)
    row = max(0, 3 * min(width, 2 * SIDE) + (0 if valid else draw(_PAD)))
    rows = min(height, 2 * SIDE)  # the bytes of at most 192 rows: a huge declared size does not allocate
    size = {"exact": rows * row, "short": max(0, rows * row - 1), "long": rows * row + 3, "empty": 0}[
        "exact" if valid else draw(_BYTES)]
    data = np.random.default_rng(seed).integers(0, 256, size, dtype=np.uint8).tobytes()
    msg = Image(height=height, width=width, encoding=encoding, step=row, data=data)
    msg.header.stamp = to_stamp(stamp)
    ok = encoding == "rgb8" and (height, width) == (SIDE, SIDE) and row >= 3 * SIDE and len(data) == height * row
    return msg, ok


def draw_proprio(draw: st.DrawFn, stamp: int, dim: int) -> tuple[JointState, bool]:
    """A proprioception JointState and whether its positions are valid (``dim`` finite values of magnitude at
    most ``max_abs_value``)."""
    valid = np.random.default_rng(stamp % 2**32).normal(size=dim)
    values, ok = (valid.astype(np.float32), True) if draw(MOSTLY) else draw_payload(
        draw, valid, 8 * dim, DEFAULT_MAX_ABS_VALUE)
    msg = JointState(name=[f"p{i}" for i in range(len(values))], position=[float(v) for v in values])
    msg.header.stamp = to_stamp(stamp)
    return msg, ok


def draw_policy_event(draw: st.DrawFn, node: PolicyNode, stamp: int) -> RolloutEvent:
    """A START or END (or an event code that means nothing), mostly of the running rollout."""
    running = node.session.running
    rollout_id = running.rollout_id if running is not None and draw(MOSTLY) else draw(ROLLOUT_IDS)
    kind = draw(st.one_of(st.sampled_from([RolloutEvent.EVENT_START, RolloutEvent.EVENT_END]), UINT8))
    return rollout_event_msg(rollout_id, kind, stamp, outcome=draw(UINT8), task=draw(TEXT), scenario=draw(TEXT))


class PolicyLedger:
    """What the policy node published, checked against what it was given."""

    def __init__(self, node: PolicyNode) -> None:
        self.node = node
        self.embeddings = record(node.fiper.embeddings)
        self.batches = record(node.fiper.batches)
        self.commands = record(node._command_pub)
        self.valid_parts: dict[int, set[str]] = {}
        self.steps: dict[int, int] = {}
        self.checked = 0

    def sent(self, stamp: int, key: str, ok: bool) -> None:
        if ok:
            self.valid_parts.setdefault(stamp, set()).add(key)

    def check(self) -> None:
        node = self.node
        assert set(node.rejected) <= set(REASONS), node.rejected
        assert len(node.sync) <= node.sync.max_pending
        assert len(self.embeddings) == len(self.batches) == len(self.commands) == node.published
        config = node.policy.config
        for embedding, batch, command in zip(self.embeddings[self.checked:], self.batches[self.checked:],
                                             self.commands[self.checked:], strict=True):
            stamp = stamp_ns(embedding.header.stamp)
            assert self.valid_parts.get(stamp) == {"wrist_rgb", "third_rgb", "proprio"}, \
                f"a step from a tick with a rejected or missing part: {stamp}"
            address = (embedding.rollout_id, embedding.step)
            assert (batch.rollout_id, batch.step) == (command.rollout_id, command.step) == address
            assert stamp_ns(batch.header.stamp) == stamp_ns(command.header.stamp) == stamp
            expected = self.steps.get(embedding.rollout_id, -1) + 1
            assert embedding.step in (0, expected), f"rollout {embedding.rollout_id}: step {embedding.step} after " \
                                                    f"{expected - 1}"  # 0: the rollout id started again
            self.steps[embedding.rollout_id] = embedding.step
            assert list(embedding.shape) == [config.embed_dim] and len(embedding.data) == config.embed_dim
            assert (batch.batch_size, batch.horizon, batch.action_dim, batch.exec_steps) == (
                node.batch_size, config.horizon, config.action_dim, config.exec_steps)
            assert (command.num_actions, command.action_dim, command.action_space) == (
                config.exec_steps, config.action_dim, config.action_space)
        self.checked = len(self.embeddings)


@fuzz(20)
@given(data=st.data())
def test_the_policy_node_survives_any_observation_and_acts_only_on_valid_ones(
        context: Context, model: Path, data: st.DataObject) -> None:
    node = bring_up(PolicyNode(context=context, namespace="/fiper", parameter_overrides=node_params(
        model=str(model), start_wait_s=60.0), **NODE_KWARGS))
    ledger = PolicyLedger(node)
    try:
        topics = callbacks(node)
        proprio_dim = node.policy.config.proprio_dim
        stamps = st.one_of(st.integers(1, 40).map(lambda k: k * 100_000_000), st.integers(0, VALID_STAMP - 124))
        for n in range(data.draw(st.integers(1, 40), label="messages")):
            kind, stamp = data.draw(POLICY_INPUTS), data.draw(stamps)
            rejected = node.rejected.total() - node.rejected["unknown_rollout"]
            if kind == "event":
                msg = draw_policy_event(data.draw, node, stamp)
                note(f"event {msg.event} of rollout {msg.rollout_id} at {stamp}")
                topics["/fiper/rollout_events"](msg)
                node._on_started_step()  # the guard condition's callback: a waiting tick's step
            elif kind == "diagnostics":
                node.publish_diagnostics()
            else:
                parts: list[tuple[str, Any, bool]] = []
                keys = list(IMAGE_TOPICS) + ["proprio"] if kind == "tick" else [
                    data.draw(st.sampled_from(["wrist_rgb", "third_rgb"])) if kind == "image" else "proprio"]
                for key in keys:
                    msg, ok = (draw_proprio(data.draw, stamp, proprio_dim) if key == "proprio"
                               else draw_image(data.draw, stamp, n))
                    parts.append((key, msg, ok))
                for key, msg, ok in parts:
                    note(f"{key} at {stamp}: {'valid' if ok else 'bad'}")
                    ledger.sent(stamp, key, ok)
                    before = node.rejected.total() - node.rejected["unknown_rollout"]
                    topics["/sim/proprio" if key == "proprio" else IMAGE_TOPICS[key]](msg)
                    after = node.rejected.total() - node.rejected["unknown_rollout"]
                    assert after - before == (0 if ok else 1), (key, ok, node.rejected)
                rejected = node.rejected.total() - node.rejected["unknown_rollout"]
            assert node.rejected.total() - node.rejected["unknown_rollout"] >= rejected
            ledger.check()
        # afterwards: a valid rollout is acted on exactly as a fresh PolicySession acts on it
        oracle = PolicySession(node.policy, None, lambda error: None)
        topics["/fiper/rollout_events"](rollout_event_msg(VALID_ID, RolloutEvent.EVENT_START, VALID_STAMP))
        node._on_started_step()
        oracle.start(VALID_ID, VALID_STAMP)
        first = len(ledger.embeddings)
        for t in range(3):
            stamp = VALID_STAMP + t * 100_000_000
            observation = random_observation(node.policy.config, seed=t)
            for key, topic in IMAGE_TOPICS.items():
                image = Image(height=SIDE, width=SIDE, encoding="rgb8", step=3 * SIDE,
                              data=observation[key].tobytes())
                image.header.stamp = to_stamp(stamp)
                ledger.sent(stamp, key, True)
                topics[topic](image)
            proprio = JointState(position=[float(v) for v in observation["proprio"]])
            proprio.header.stamp = to_stamp(stamp)
            ledger.sent(stamp, "proprio", True)
            topics["/sim/proprio"](proprio)
            assert oracle.observe(stamp, observation, 0)
            action = oracle.compute(oracle.begin())
            embedding, batch = ledger.embeddings[first + t], ledger.batches[first + t]
            assert (embedding.rollout_id, embedding.step) == (VALID_ID, t)
            np.testing.assert_array_equal(np.asarray(embedding.data, np.float32), action.embedding)
            np.testing.assert_array_equal(np.asarray(batch.data, np.float32), action.chunks.ravel())
        ledger.check()
    finally:
        node.destroy_node()


# the sim bridge ----------------------------------------------------------------------------------------
_TASK = st.one_of(st.sampled_from(["sorting", "sorting", "pusht", "stacking", ""]), TEXT)
_SCENARIO = st.one_of(st.sampled_from(["id", "id", ""]), TEXT)
_SPACES = st.one_of(st.sampled_from(["ee_position", "joint_velocity", "joint_position", ""]), TEXT)
BRIDGE_INPUTS = st.sampled_from(["command", "command", "command", "timer", "timer", "timer", "timer", "reset", "halt"])


def draw_command(draw: st.DrawFn, node: BridgeNode) -> tuple[ActionCommand, bool]:
    """An ActionCommand, mostly for the running rollout's next step, and whether the bridge must take it."""
    session = node.session
    rollout, env = session.rollout, session.env
    task = rollout.task if rollout is not None else "sorting"
    dim, horizon = (env.action_dim, env.horizon) if env is not None else (2, 8)
    rollout_id = rollout.rollout_id if rollout is not None and draw(MOSTLY) else draw(ROLLOUT_IDS)
    step = rollout.policy_step if rollout is not None and draw(MOSTLY) else draw(st.one_of(st.integers(0, 5), UINT32))
    space = ACTION_SPACES[task] if draw(MOSTLY) else draw(_SPACES)
    n = draw(st.integers(1, min(4, horizon))) if draw(MOSTLY) else draw(st.one_of(st.sampled_from(
        [0, horizon, horizon + 1]), UINT32))
    d = dim if draw(MOSTLY) else draw(st.one_of(st.sampled_from([0, 1, dim + 1]), UINT32))
    rows = max(1, min(n, horizon))
    if ACTION_SPACES[task] == "ee_position" and env is not None:  # small moves from where the hand is
        here = session.observation()["proprio"][:dim]
        valid = (here + np.random.default_rng(step % 2**32).normal(0.0, 0.01, (rows, dim))).astype(np.float32)
    else:
        valid = np.random.default_rng(step % 2**32).normal(0.0, 0.1, (rows, dim)).astype(np.float32)
    data, ok = (valid.ravel(), True) if draw(MOSTLY) else draw_payload(draw, valid, 4 * valid.size,
                                                                      DEFAULT_MAX_ABS_VALUE)
    msg = ActionCommand(rollout_id=rollout_id, step=step, num_actions=n, action_dim=d, data=float_array(data),
                        action_space=space, observation_history=draw(st.one_of(st.integers(0, 3), UINT32)))
    msg.header.stamp = draw(STAMP)
    ok = (ok and rollout is not None and rollout_id == rollout.rollout_id and not session.busy
          and step == rollout.policy_step and space == ACTION_SPACES[task] and d == dim and 1 <= n <= horizon
          and data.size == n * d)
    return msg, ok


def known_scenario(task: str, scenario: str) -> bool:
    """Whether the simulation has this task and scenario."""
    try:
        get_scenario(task, scenario)
    except ScenarioError:
        return False
    return True


def check_events(events: list[RolloutEvent]) -> None:
    """START, END, START, END...: every rollout the bridge starts it ends once, before it starts the next one."""
    running = None
    for msg in events:
        if msg.event == RolloutEvent.EVENT_START:
            assert running is None, f"rollout {msg.rollout_id} started while {running} runs"
            running = msg.rollout_id
        else:
            assert msg.event == RolloutEvent.EVENT_END and msg.rollout_id == running, (msg, running)
            running = None


@fuzz(20)
@given(data=st.data())
def test_the_sim_bridge_survives_any_command_and_then_simulates_as_the_sim(context: Context,
                                                                          data: st.DataObject) -> None:
    node = bring_up(BridgeNode(context=context, parameter_overrides=node_params(
        images=False, realtime_factor=0.0, sim_time=True, publish_rate_hz=0.0, observation_resend_s=0.0),
        **NODE_KWARGS))
    events = record(node._event_pub)
    proprio = record(node._proprio_pub)
    on_action = callbacks(node)["/sim/action"]
    try:
        for _ in range(data.draw(st.integers(1, 30), label="messages")):
            kind = data.draw(BRIDGE_INPUTS)
            if node.session.rollout is None and data.draw(MOSTLY):  # mostly a rollout runs
                kind = "reset"
            if kind == "reset":
                request = ResetRollout.Request(task=data.draw(_TASK), scenario=data.draw(_SCENARIO),
                                               seed=data.draw(UINT64))
                running = node.session.rollout
                task = request.task or (running.task if running is not None else "sorting")
                response = node._on_reset(request, ResetRollout.Response())  # the service callback
                note(f"reset {request.task!r}/{request.scenario!r} seed {request.seed}: {response.message}")
                assert response.success == known_scenario(task, request.scenario or "id"), response.message
            elif kind == "halt":
                note("halt")
                assert node._on_halt(Trigger.Request(), Trigger.Response()).success
            elif kind == "timer":
                if node._step_timer is not None:  # the step timer's callback, once it exists
                    node._on_step_timer()
            else:
                msg, ok = draw_command(data.draw, node)
                rollout = node.session.rollout
                taken, rejected = (rollout.policy_step if rollout is not None else 0), node.rejected.copy()
                note(f"command of rollout {msg.rollout_id} step {msg.step}: {msg.num_actions} x {msg.action_dim} "
                     f"{msg.action_space!r}, {'valid' if ok else 'bad'}")
                on_action(msg)
                accepted = rollout is not None and rollout.policy_step == taken + 1
                new = node.rejected - rejected
                new.pop("internal_error", None)  # the simulation failed on what it took: the rollout ends
                assert accepted == ok and new.total() == (0 if ok else 1), (ok, node.rejected - rejected)
            assert set(node.rejected) <= set(REASONS), node.rejected
            env = node.session.env
            assert env is None or len(node.session._pending) <= env.horizon
            check_events(events)
        # afterwards: a rollout is simulated exactly as the simulation itself does it
        seed = 2**33 + 5
        response = node._on_reset(ResetRollout.Request(task="sorting", scenario="id", seed=seed),
                                  ResetRollout.Response())
        assert response.success, response.message
        shadow = make_env("sorting", "id", seed, images=False)
        shadow.reset()
        try:
            for step in range(3):
                x, y = proprio[-1].position[:2]
                chunk = np.tile(np.array([x + 0.02, y], np.float32), (4, 1))
                ticks = len(proprio)
                on_action(ActionCommand(rollout_id=response.rollout_id, step=step, num_actions=4, action_dim=2,
                                        data=float_array(chunk), action_space="ee_position"))
                for _ in range(10):
                    if len(proprio) > ticks:
                        break
                    node._on_step_timer()
                for action in chunk.astype(np.float64):
                    shadow.step(action)
                assert len(proprio) == ticks + 1
                np.testing.assert_array_equal(np.asarray(proprio[-1].position),
                                              np.asarray(shadow.observation()["proprio"], np.float64))
        finally:
            shadow.close()
        check_events(events)
    finally:
        node.destroy_node()


# what the fuzzing found, as a focused regression test ---------------------------------------------------
def test_a_command_while_one_executes_is_rejected_under_a_named_reason() -> None:
    # The bridge counted such a command as rejected.busy, a reason of its own outside validation.REASONS (the
    # named reasons every node's diagnostics use).
    session = BridgeSession(images=False)
    try:
        rollout, _ = session.start("sorting", "id", 1)
        here = session.observation()["proprio"][:2].astype(np.float32)
        session.accept(rollout.rollout_id, 0, "ee_position", 4, 2, np.tile(here, 4), 0)
        with pytest.raises(InputRejected) as info:
            session.accept(rollout.rollout_id, 1, "ee_position", 4, 2, np.tile(here, 4), 0)
        assert info.value.reason == "busy" and info.value.reason in REASONS
    finally:
        session.close()
