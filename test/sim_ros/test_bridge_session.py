"""The bridge's rollout logic without DDS: rollout ids, command checks, outcomes."""
from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest
import rclpy
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter

from fiper_msgs.msg import ActionCommand
from fiper_ros.runtime.validation import InputRejected
from sim_bridge.bridge_session import ACTION_SPACES, JOINT_NAMES, PROPRIO_NAMES, BridgeSession, bridge_rollout_id
from sim_bridge.scenarios import ScenarioError
from sim_bridge.tasks import TASKS


@pytest.fixture
def session() -> Iterator[BridgeSession]:
    s = BridgeSession(images=False)
    yield s
    s.close()


def test_task_tables_match_the_tasks_and_messages() -> None:
    spaces = {ActionCommand.ACTION_SPACE_EE_POSITION, ActionCommand.ACTION_SPACE_JOINT_VELOCITY}
    assert set(ACTION_SPACES) == set(PROPRIO_NAMES) == set(TASKS)
    assert set(ACTION_SPACES.values()) <= spaces
    assert all(len(PROPRIO_NAMES[name]) == task.proprio_dim for name, task in TASKS.items())
    assert len(JOINT_NAMES) == 9


def test_rollout_ids_are_unique_and_carry_counter_and_seed() -> None:
    seeds = [0, 1, 2**32 + 1, 2**40, 0, 7, 7] * 7  # repeated seeds, seeds equal modulo 2**32
    ids = {bridge_rollout_id(counter, seed) for counter, seed in enumerate(seeds, start=1)}
    assert len(ids) == len(seeds)  # the run's counter tells them apart
    assert bridge_rollout_id(3, 17) >> 32 == 3 and bridge_rollout_id(3, 17) & 0xFFFFFFFF == 17
    assert 0 not in ids


def _reason(session: BridgeSession, *args: object) -> str:
    with pytest.raises(InputRejected) as info:
        session.accept(*args, 0)  # type: ignore[arg-type]
    return info.value.reason


def test_commands_are_checked(session: BridgeSession) -> None:
    ok = np.zeros(4 * 2, np.float32)
    assert _reason(session, 1, 0, "ee_position", 4, 2, ok) == "unknown_rollout"  # nothing running
    rollout, aborted = session.start("sorting", "id", 1)
    assert aborted is None and rollout.max_steps == 75
    rid = rollout.rollout_id
    nan = ok.copy()
    nan[3] = np.inf
    assert _reason(session, rid + 1, 0, "ee_position", 4, 2, ok) == "unknown_rollout"
    assert _reason(session, rid, 1, "ee_position", 4, 2, ok) == "out_of_order_step"
    assert _reason(session, rid, 0, "joint_velocity", 4, 2, ok) == "action_space"
    assert _reason(session, rid, 0, "ee_position", 4, 3, np.zeros(12, np.float32)) == "shape"
    assert _reason(session, rid, 0, "ee_position", 0, 2, np.zeros(0, np.float32)) == "shape"
    assert _reason(session, rid, 0, "ee_position", 9, 2, np.zeros(18, np.float32)) == "shape"  # > H = 8
    assert _reason(session, rid, 0, "ee_position", 4, 2, ok[:-1]) == "shape"
    assert _reason(session, rid, 0, "ee_position", 4, 2, nan) == "non_finite"
    tcp = session.observation()["proprio"][:2]
    session.accept(rid, 0, "ee_position", 4, 2, np.tile(tcp, 4), 0)
    assert session.busy
    assert _reason(session, rid, 1, "ee_position", 4, 2, ok) == "busy"
    while session.busy:
        assert session.execute_one() is None
    assert session.env is not None and session.env.control_step == 4
    assert _reason(session, rid, 0, "ee_position", 4, 2, ok) == "duplicate_step"


def test_a_command_asks_for_the_observations_of_its_last_control_steps(session: BridgeSession) -> None:
    """``observation_history`` n: the states of the command's last n control steps before the tick's
    (at most num_actions - 1) are due, the tick's own is not."""
    rollout, _ = session.start("sorting", "id", 5)
    tcp = session.observation()["proprio"][:2]
    for step, (history, due) in enumerate([(0, [False] * 4), (1, [False, False, True, False]),
                                           (5, [True, True, True, False])]):
        session.accept(rollout.rollout_id, step, "ee_position", 4, 2, np.tile(tcp, 4), history)
        seen = []
        while session.busy:
            assert session.execute_one() is None
            seen.append(session.observation_due)
        assert seen == due, history


def test_outcomes(session: BridgeSession) -> None:
    rollout, _ = session.start("sorting", "id", 2)
    assert session.end("nothing") is not None and session.end("twice") is None
    with pytest.raises(ScenarioError, match=r"^unknown scenario 'no_such_scenario' for sorting; scenarios: \["):
        session.start("sorting", "no_such_scenario", 0)
    rollout, _ = session.start("sorting", "id", 2)
    with pytest.raises(ScenarioError, match=r"^unknown task 'no_such_task'; tasks: \["):
        session.start("no_such_task", "id", 0)
    assert session.rollout is rollout  # a refused reset keeps the rollout running
    tcp = session.observation()["proprio"][:2]
    session.accept(rollout.rollout_id, 0, "ee_position", 8, 2, np.tile(tcp, 8), 0)
    new, aborted = session.start("sorting", "id", 3)
    assert aborted is not None and (aborted.outcome, aborted.reason, aborted.policy_step) == ("failure", "aborted", 1)
    assert not session.busy and new.rollout_id >> 32 == 3
    step, ended = 0, None
    while ended is None:  # hold still until the time limit
        session.accept(new.rollout_id, step, "ee_position", 4, 2, np.tile(tcp, 4), 0)
        step += 1
        while ended is None and session.busy:
            ended = session.execute_one()
    assert (ended.outcome, ended.reason, ended.policy_step, ended.control_step) == ("failure", "timeout", 75, 300)
    assert session.rollout is None and not session.busy


def test_a_policy_step_cap_ends_rollouts_as_a_timeout_after_the_last_command() -> None:
    session = BridgeSession(images=False, max_policy_steps=2)
    try:
        rollout, _ = session.start("sorting", "id", 4)
        assert rollout.max_steps == 2
        tcp = session.observation()["proprio"][:2]
        ended = None
        for step in range(2):
            assert ended is None
            session.accept(rollout.rollout_id, step, "ee_position", 4, 2, np.tile(tcp, 4), 0)
            while ended is None and session.busy:
                ended = session.execute_one()
        assert ended is not None
        assert (ended.outcome, ended.reason, ended.policy_step, ended.control_step) == ("failure", "timeout", 2, 8)
    finally:
        session.close()
    loose = BridgeSession(images=False, max_policy_steps=500)
    try:
        assert loose.start("pusht", "id", 0)[0].max_steps == 38  # a cap above the task's limit changes nothing
    finally:
        loose.close()


def test_start_on_activate_and_deactivate(ros_domain: int) -> None:
    from sim_bridge.bridge_node import NODE_CLASS

    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    params = {"start_on_activate": True, "images": False, "task": "pusht", "scenario": "t_shape", "seed": 11}
    node = NODE_CLASS(context=context, parameter_overrides=[Parameter(k, value=v) for k, v in params.items()])
    executor.add_node(node)
    try:
        for _ in range(50):
            executor.spin_once(timeout_sec=0.05)
            if node.session is not None and node.session.rollout is not None:
                break
        rollout = node.session.rollout
        assert (rollout.task, rollout.scenario, rollout.seed, rollout.max_steps) == ("pusht", "t_shape", 11, 38)
        assert node.lifecycle_state() == "active"
        node.trigger_deactivate()
        assert node.session.rollout is None and node.ended == {"deactivated": 1}
    finally:
        executor.remove_node(node)
        node.destroy_node()
        executor.shutdown()
        rclpy.try_shutdown(context=context)
