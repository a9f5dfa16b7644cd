"""The policy node's rollout logic without ROS: START / END, which ticks are acted on, steps, noise, T_h."""
from __future__ import annotations

import numpy as np
import pytest
from helpers.policy_fixtures import random_observation, tiny_policy

from fiper_ros.policy.noise import sampling_generator
from fiper_ros.policy.policy import Policy
from fiper_ros.policy.session import PolicySession
from fiper_ros.runtime.validation import UNKNOWN_ROLLOUT, InputRejected

MS = 1_000_000
SEED = 42
RID = (3 << 32) | SEED  # the bridge's third rollout, seed 42


@pytest.fixture(scope="module")
def policy() -> Policy:
    return tiny_policy()


@pytest.fixture
def rejected() -> list[InputRejected]:
    return []


@pytest.fixture
def session(policy: Policy, rejected: list[InputRejected]) -> PolicySession:
    return PolicySession(policy, None, rejected.append, start_wait_ns=500 * MS)


def test_steps_and_noise_follow_the_rollout(session: PolicySession, policy: Policy) -> None:
    obs = [random_observation(policy.config, seed) for seed in range(3)]
    assert not session.start(RID, 1000 * MS, "sorting", "id")
    generator = sampling_generator(SEED)  # run_episode(seed=42) draws the same noise
    for step, stamp in enumerate((1000 * MS, 1400 * MS, 1800 * MS)):
        assert session.observe(stamp, obs[step], 0)
        action = session.compute(session.begin())
        embedding, chunks = policy.act([obs[step]], None, generator)
        assert (action.rollout_id, action.step, action.stamp) == (RID, step, stamp)
        np.testing.assert_array_equal(action.embedding, embedding)
        np.testing.assert_array_equal(action.chunks, chunks)
        np.testing.assert_array_equal(action.command, chunks[0, : policy.config.exec_steps])
    assert action.chunks.shape == (policy.config.sample_batch, policy.config.horizon, policy.config.action_dim)
    ended = session.end(RID, 2000 * MS, "success")
    assert ended is not None and ended.summary() == f"rollout {RID} sorting/id: 3 policy steps, outcome success"
    # a new rollout of the same seed starts over: step 0, the same noise
    assert not session.start(RID + (1 << 32), 2100 * MS)
    assert session.observe(2100 * MS, obs[0], 0)
    again = session.compute(session.begin())
    first = policy.act([obs[0]], None, sampling_generator(SEED))[1]
    assert again.step == 0 and np.array_equal(again.chunks, first)
    assert session.rollouts_seen == 2


def test_batch_override(policy: Policy) -> None:
    session = PolicySession(policy, 3, lambda error: None)
    session.start(RID, 0)
    assert session.observe(0, random_observation(policy.config), 0)
    assert session.compute(session.begin()).chunks.shape[0] == 3


def test_a_step_taken_before_an_end_is_computed_but_its_rollout_no_longer_runs(session: PolicySession,
                                                                              policy: Policy) -> None:
    obs = random_observation(policy.config)
    session.start(RID, 1000 * MS)
    assert session.observe(1000 * MS, obs, 0)
    step = session.begin()
    assert session.is_running(RID) and not session.is_running(RID + 1)
    ended = session.end(RID, 1100 * MS, "failure")  # while the step computes
    assert ended is not None and ended.steps == 1 and not session.is_running(RID)
    action = session.compute(step)
    assert (action.rollout_id, action.step, action.stamp) == (RID, 0, 1000 * MS)
    np.testing.assert_array_equal(action.chunks, policy.act([obs], None, sampling_generator(SEED))[1])
    with pytest.raises(RuntimeError):
        session.begin()  # no rollout runs


def test_late_and_unknown_ticks_are_not_acted_on(session: PolicySession, policy: Policy,
                                                  rejected: list[InputRejected]) -> None:
    obs = random_observation(policy.config)
    session.start(RID, 1000 * MS)
    assert session.observe(1000 * MS, obs, 0)
    session.compute(session.begin())
    assert session.end(RID + 1, 1500 * MS, "failure") is None  # not the running rollout: ignored
    assert session.end(RID, 1500 * MS, "failure") is not None
    assert not session.observe(1400 * MS, obs, 0)  # overtook the END: late, ignored
    assert session.late == 1 and not rejected
    session.start(RID + (1 << 32), 2000 * MS)
    assert not session.observe(1200 * MS, obs, 0)  # of the ended rollout
    assert not session.observe(1900 * MS, obs, 0)  # after the END, before the START: nobody's
    assert session.late == 2 and [e.reason for e in rejected] == [UNKNOWN_ROLLOUT]
    with pytest.raises(RuntimeError):
        PolicySession(policy, None, rejected.append).begin()  # nothing to act on


def test_a_tick_waits_for_its_start(session: PolicySession, policy: Policy, rejected: list[InputRejected]) -> None:
    obs = random_observation(policy.config)
    assert not session.observe(1000 * MS, obs, now_ns=0)  # overtook its START
    assert session.waiting and not rejected
    assert session.start(RID, 1000 * MS)  # act on it now
    assert not session.waiting and session.compute(session.begin()).stamp == 1000 * MS
    session.end(RID, 1200 * MS, "failure")
    # without a START the waiting tick expires as unknown_rollout
    assert not session.observe(3000 * MS, obs, now_ns=0)
    session.expire(400 * MS)
    assert session.waiting and not rejected
    session.expire(501 * MS)
    assert not session.waiting and [e.reason for e in rejected] == [UNKNOWN_ROLLOUT]
    # a newer tick displaces an older waiting one; a START after a waiting tick does not take it
    session.observe(4000 * MS, obs, now_ns=0)
    session.observe(4100 * MS, obs, now_ns=0)
    assert len(rejected) == 2
    assert not session.start(RID + (1 << 32), 4200 * MS)
    assert len(rejected) == 3 and not session.waiting


def test_a_start_without_end_replaces_the_running_rollout(session: PolicySession, policy: Policy,
                                                          rejected: list[InputRejected]) -> None:
    obs = random_observation(policy.config)
    session.start(RID, 1000 * MS)
    assert not session.start(RID, 1000 * MS)  # repeated START: nothing changes
    assert session.observe(1000 * MS, obs, 0)
    session.compute(session.begin())
    assert session.running is not None and session.running.steps == 1
    session.start(RID + (1 << 32), 2000 * MS)  # the END was lost
    assert session.last_ended is not None and session.last_ended.rollout_id == RID
    assert not session.observe(1500 * MS, obs, 0) and session.late == 1 and not rejected


def test_history_holds_the_control_steps_before_each_tick() -> None:
    """T_h = 2: each command asks for the observation of the control step before the next tick; it joins
    the history without a step of its own, so the step acts on [that observation, the tick], as
    run_episode's history of consecutive control steps."""
    policy = tiny_policy("stacking")  # T_h = 2
    assert policy.config.obs_horizon == 2 and policy.config.exec_steps >= 2
    session = PolicySession(policy, 4, lambda error: None)
    assert session.history_frames == 1
    obs = [random_observation(policy.config, seed) for seed in range(5)]
    session.start(RID, 0)
    assert session.observe(0, obs[0], 0)
    embeddings = [session.compute(session.begin()).embedding]
    for step, (before, tick) in enumerate(((obs[1], obs[2]), (obs[3], obs[4])), start=1):
        assert not session.observe((2 * step - 1) * MS, before, 0)  # history only
        assert session.observe(2 * step * MS, tick, 0)
        action = session.compute(session.begin())
        assert (action.step, action.stamp) == (step, 2 * step * MS)
        embeddings.append(action.embedding)
    np.testing.assert_array_equal(embeddings[0], policy.embed([obs[0]]))  # the first tick repeated
    np.testing.assert_allclose(embeddings[1], policy.embed([obs[1], obs[2]]), atol=1e-6)
    np.testing.assert_allclose(embeddings[2], policy.embed([obs[3], obs[4]]), atol=1e-6)
    assert session.running is not None and len(session.running.history) == 2
    # T_h = 1 asks for nothing: every observation is a tick
    assert PolicySession(tiny_policy(), None, lambda error: None).history_frames == 0
