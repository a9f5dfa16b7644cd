"""Faults of the suite's own processes, over real DDS with the nodes as separate processes (``fiper launch``):
a dead (SIGKILL) or hung (SIGSTOP) scoring node is said UNKNOWN, and a dead or hung fusion node makes the
supervisor halt on silence, within ``DEADLINE_PERIODS`` (2.5) policy periods and one check of the last word heard;
with ``respawn: true`` the node comes back by itself and the next rollout is judged normally; one message with a
step far ahead wedges nothing.

A scoring node's fault is counted on the fusion node's own schedule: the repeats of its last verdict (one per
measured period of silence) before the UNKNOWN, at most ``floor(DEADLINE_PERIODS)``, which no load can stretch
(the count of the driver's 10 Hz steps was: the deadline runs from the last score's arrival, which a loaded ACE
node delays past its step, and the check that says it runs late). The fusion node's own fault is counted in
policy steps the driver published after it (the supervisor's schedule is not seen from outside): at most
``ceil(DEADLINE_PERIODS + CHECK_PERIOD_S / POLICY_PERIOD_S)``."""
from __future__ import annotations

import math
import os
import signal
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg
from fiper_ros.nodes.supervisor_node import CHECK_PERIOD_S
from fiper_ros.runtime.stats import DEADLINE_PERIODS
from helpers.launch import POLICY_PERIOD_S, Rig, open_rig, suite_config
from helpers.suite import STEP_NS
from helpers.synthetic import FAIL_FROM, LENGTH, make_rollout

#: The promise of the supervisor: a dead or hung fusion node goes unnoticed for at most this many policy steps.
NOTICED_WITHIN_STEPS = math.ceil(DEADLINE_PERIODS + CHECK_PERIOD_S / POLICY_PERIOD_S)
NODES = ("rnd_oe_node", "ace_node", "fusion_node")


@pytest.fixture
def rig_factory(tmp_path: Path, calibration_dir: Path, ros_domain: int) -> Iterator[Callable[[bool], Rig]]:
    made: list[Rig] = []

    def make(respawn: bool) -> Rig:
        rig = open_rig(suite_config(tmp_path / "suite.yaml", calibration_dir, respawn=respawn), ros_domain)
        made.append(rig)
        for name in NODES:
            rig.wait_healthy(name)
        return rig

    yield make
    for rig in made:
        rig.close()


def _unknown_naming(rig: Rig, rollout_id: int, detector: str) -> Callable[[], bool]:
    count = len(rig.driver.alarms)
    return lambda: any(m.rollout_id == rollout_id and m.state == FailureAlarm.STATE_UNKNOWN and detector in m.reason
                       for m in rig.driver.alarms[count:])


def _repeats_before_unknown(rig: Rig, rollout_id: int, detector: str) -> int:
    """How often the fusion node repeated its last verdict of ``rollout_id`` (an OK heartbeat of its step: one per
    measured period of silence) before its first UNKNOWN naming ``detector``."""
    said = [m for m in rig.driver.alarms if m.rollout_id == rollout_id]
    unknown = next(i for i, m in enumerate(said) if m.state == FailureAlarm.STATE_UNKNOWN and detector in m.reason)
    verdict = max(i for i, m in enumerate(said[:unknown]) if not m.heartbeat)
    return sum(m.heartbeat and (m.step, m.state) == (said[verdict].step, FailureAlarm.STATE_OK)
               for m in said[verdict + 1:unknown])


def _halted(rig: Rig) -> Callable[[], bool]:
    count = len(rig.halts)
    return lambda: len(rig.halts) > count


@pytest.mark.slow
@pytest.mark.parametrize("name", NODES)
def test_a_hung_or_dead_node_is_noticed_within_the_promised_periods_and_respawn_restores_judging(
        rig_factory: Callable[[bool], Rig], name: str) -> None:
    rig = rig_factory(True)
    detector = name.removesuffix("_node")
    healthy = make_rollout(700)

    def noticed(rollout_id: int) -> Callable[[], bool]:
        return _halted(rig) if name == "fusion_node" else _unknown_naming(rig, rollout_id, detector)

    def within_the_promise(rollout_id: int, steps: int) -> bool:
        if name == "fusion_node":
            return steps <= NOTICED_WITHIN_STEPS
        return _repeats_before_unknown(rig, rollout_id, detector) <= math.floor(DEADLINE_PERIODS)

    # 1. SIGSTOP (hung): noticed within the promise; SIGCONT lets it go on.
    rig.start(1)
    assert all(m.state == FailureAlarm.STATE_OK for m in rig.run_paced(1, healthy, range(5)).values())
    seen = noticed(1)
    pid = rig.launch.pid_of(name)
    os.kill(pid, signal.SIGSTOP)
    try:
        steps = rig.steps_until(seen, 1, healthy, 5)
        assert within_the_promise(1, steps), steps
    finally:
        os.kill(pid, signal.SIGCONT)
    rig.driver.end(1, True)
    rig.wait_healthy(name)

    # 2. SIGKILL (dead): noticed within the promise.
    rig.start(2)
    rig.run_paced(2, healthy, range(5))
    seen = noticed(2)
    os.kill(rig.launch.pid_of(name), signal.SIGKILL)
    steps = rig.steps_until(seen, 2, healthy, 5)
    assert within_the_promise(2, steps), steps
    assert rig.spin_until(lambda: len(rig.launch.pids_of(name)) == 2, timeout=30), "\n".join(rig.launch.lines[-20:])
    rig.driver.end(2, True)

    # 3. respawned by the launcher: the calibration is reloaded and the next rollouts are judged normally.
    rig.wait_healthy(name)
    assert any(f"respawning {name}" in line for line in rig.launch.lines)
    rig.start(3)
    ok = rig.run_paced(3, healthy, range(LENGTH))
    assert [ok[t].state for t in range(LENGTH)] == [FailureAlarm.STATE_OK] * LENGTH, \
        [(t, ok[t].state, ok[t].reason) for t in range(LENGTH) if ok[t].state != FailureAlarm.STATE_OK]
    failing = make_rollout(701, fail=True)
    rig.start(4)
    states = rig.run_paced(4, failing, range(LENGTH))
    assert min(t for t, m in states.items() if m.state == FailureAlarm.STATE_ALARM) == FAIL_FROM


@pytest.mark.slow
def test_a_step_far_ahead_is_rejected_and_wedges_nothing(rig_factory: Callable[[bool], Rig]) -> None:
    # Issue #18: a started rollout got an ObservationEmbedding with step 4294967295; the RND-OE node pushed
    # one 0 per missing step (4e9 pushes), stopped asserting liveliness, and no later rollout got a verdict.
    rig = rig_factory(False)
    rollout = make_rollout(702)
    rig.start(1)
    rig.run_paced(1, rollout, range(3))
    far = 2**32 - 1
    rig.driver.embeddings.publish(embedding_msg(1, far, (far + 1) * STEP_NS, rollout.embeddings[3]))
    rig.driver.batches.publish(action_batch_msg(1, far, (far + 1) * STEP_NS, rollout.actions[3], rollout.exec_steps,
                                                "ee_position"))
    states = rig.run_paced(1, rollout, range(3, 8))  # the same rollout goes on being judged
    assert all(states[t].state == FailureAlarm.STATE_OK for t in range(8))
    rig.driver.end(1, True)
    rig.start(2)
    later = rig.run_paced(2, rollout, range(LENGTH))
    assert [later[t].state for t in range(LENGTH)] == [FailureAlarm.STATE_OK] * LENGTH
    for node in ("rnd_oe_node", "ace_node"):
        key = f"fiper: /fiper/{node}"
        assert rig.spin_until(lambda k=key: rig.driver.diagnostics.get(k, {}).get("rejected.step_gap") == "1"), \
            rig.driver.diagnostics.get(key)
