"""Faults of the suite's own processes, over real DDS with the nodes as separate processes (``fiper launch``):
a dead (SIGKILL) or hung (SIGSTOP) scoring node is said UNKNOWN, and a dead or hung fusion node makes the
supervisor halt on silence, within 3 policy periods of a 10 Hz policy; with ``respawn: true`` the node comes
back by itself and the next rollout is judged normally; one message with a step far ahead wedges nothing.

Time is counted in policy steps the driver published after the fault (a 10 Hz policy), so a loaded machine
stretches the suite and the count alike."""
from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import rclpy
import yaml
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from std_srvs.srv import Trigger

from fiper_msgs.msg import FailureAlarm
from fiper_ros.core.rollout import Rollout
from fiper_ros.nodes.conversions import action_batch_msg, embedding_msg
from helpers.launch import Launch
from helpers.spin import spin_until
from helpers.suite import STEP_NS, Driver
from helpers.synthetic import FAIL_FROM, LENGTH, make_rollout

POLICY_PERIOD_S = STEP_NS / 1e9
#: The promise: a fault goes unnoticed for at most this many policy steps.
NOTICED_WITHIN_STEPS = 3
NODES = ("rnd_oe_node", "ace_node", "fusion_node")


@dataclass
class Rig:
    """A launched suite (with the example supervisor), the test's driver and its halt service."""

    launch: Launch
    driver: Driver
    executor: SingleThreadedExecutor
    halts: list[float] = field(default_factory=list)

    def spin_until(self, condition: Callable[[], bool], timeout: float = 30.0) -> bool:
        return spin_until(self.executor, condition, timeout, step=0.01)

    def pace(self, seconds: float, condition: Callable[[], bool] = lambda: False) -> bool:
        """Spin for ``seconds`` of a policy period (returning early once ``condition`` holds)."""
        return self.spin_until(condition, timeout=seconds)

    def start(self, rollout_id: int) -> None:
        self.driver.start(rollout_id)
        self.pace(0.2)  # the nodes take the START before the first step (the policy resets the sim first)

    def step(self, rollout_id: int, rollout: Rollout, step: int) -> None:
        self.driver.step(rollout_id, step, rollout.embeddings[step], rollout.actions[step], rollout.exec_steps)

    def run_paced(self, rollout_id: int, rollout: Rollout, steps: range) -> dict[int, FailureAlarm]:
        """Publish ``steps`` at 10 Hz, each after the previous one's verdict arrived."""
        for step in steps:
            began = time.monotonic()
            self.step(rollout_id, rollout, step)
            assert self.spin_until(lambda s=step: s in self.driver.alarms_of(rollout_id)), \
                (rollout_id, step, "\n".join(self.launch.lines[-30:]))
            self.pace(max(0.0, POLICY_PERIOD_S - (time.monotonic() - began)))
        return self.driver.alarms_of(rollout_id)

    def steps_until(self, noticed: Callable[[], bool], rollout_id: int, rollout: Rollout, first: int) -> int:
        """Go on publishing at 10 Hz from step ``first`` until ``noticed()``; the steps published meanwhile."""
        for published, step in enumerate(range(first, rollout.length)):
            if noticed():
                return published
            began = time.monotonic()
            self.step(rollout_id, rollout, step)
            if self.pace(max(0.0, POLICY_PERIOD_S - (time.monotonic() - began)), noticed):
                return published + 1
        raise AssertionError(f"not noticed within {rollout.length - first} steps:\n" + "\n".join(self.launch.lines[-40:]))

    def wait_healthy(self, name: str) -> None:
        """Wait until ``name`` reports ACTIVE again and the driver's topics are wired to the whole suite."""
        key = f"fiper: /fiper/{name}"
        self.driver.diagnostics.pop(key, None)
        assert self.spin_until(lambda: self.driver.diagnostics.get(key, {}).get("lifecycle_state") == "active",
                               timeout=60), "\n".join(self.launch.lines[-40:])
        assert self.spin_until(lambda: self.driver.embeddings.get_subscription_count() >= 1
                               and self.driver.batches.get_subscription_count() >= 1
                               and self.driver.events.get_subscription_count() >= 4)


def _config(path: Path, calibration_dir: Path, respawn: bool) -> Path:
    share = Path(os.environ["FIPER_ROOT"]) / "fiper_ros" / "config"
    scoring = {"calibration_dir": str(calibration_dir)}
    respawning = {"respawn": respawn, "respawn_delay": 0.5}
    path.write_text(yaml.safe_dump({
        "namespace": "/fiper",
        "parameter_files": [str(share / "nodes.yaml")],
        "nodes": {
            "rnd_oe_node": {"module": "fiper_ros.nodes.rnd_oe_node", "parameters": scoring, **respawning},
            "ace_node": {"module": "fiper_ros.nodes.ace_node", "parameters": scoring, **respawning},
            "fusion_node": {"module": "fiper_ros.nodes.fusion_node", **respawning},
            "supervisor_node": {"module": "fiper_ros.nodes.supervisor_node",
                                "parameters": {"halt_service": "/test/halt", "deadline_s": 2.0}},
        },
    }))
    return path


@pytest.fixture
def rig_factory(tmp_path: Path, calibration_dir: Path, ros_domain: int) -> Iterator[Callable[[bool], Rig]]:
    made: list[tuple[Rig, Context]] = []

    def make(respawn: bool) -> Rig:
        launch = Launch(_config(tmp_path / "suite.yaml", calibration_dir, respawn), ros_domain)
        context = Context()
        rclpy.init(context=context, domain_id=ros_domain)
        executor = SingleThreadedExecutor(context=context)
        driver = Driver(context)
        rig = Rig(launch, driver, executor)

        def on_halt(request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
            del request
            rig.halts.append(time.monotonic())
            response.success = True
            return response

        driver.create_service(Trigger, "/test/halt", on_halt)
        executor.add_node(driver)
        made.append((rig, context))
        for name in NODES:
            rig.wait_healthy(name)
        return rig

    yield make
    for rig, context in made:
        rig.executor.shutdown()
        rig.driver.destroy_node()
        rclpy.try_shutdown(context=context)
        rig.launch.kill()


def _unknown_naming(rig: Rig, rollout_id: int, detector: str) -> Callable[[], bool]:
    count = len(rig.driver.alarms)
    return lambda: any(m.rollout_id == rollout_id and m.state == FailureAlarm.STATE_UNKNOWN and detector in m.reason
                       for m in rig.driver.alarms[count:])


def _halted(rig: Rig) -> Callable[[], bool]:
    count = len(rig.halts)
    return lambda: len(rig.halts) > count


@pytest.mark.slow
@pytest.mark.parametrize("name", NODES)
def test_a_hung_or_dead_node_is_noticed_within_3_periods_and_respawn_restores_judging(
        rig_factory: Callable[[bool], Rig], name: str) -> None:
    rig = rig_factory(True)
    detector = name.removesuffix("_node")
    healthy = make_rollout(700)

    def noticed(rollout_id: int) -> Callable[[], bool]:
        return _halted(rig) if name == "fusion_node" else _unknown_naming(rig, rollout_id, detector)

    # 1. SIGSTOP (hung): noticed within 3 steps; SIGCONT lets it go on.
    rig.start(1)
    assert all(m.state == FailureAlarm.STATE_OK for m in rig.run_paced(1, healthy, range(5)).values())
    seen = noticed(1)
    pid = rig.launch.pid_of(name)
    os.kill(pid, signal.SIGSTOP)
    try:
        assert rig.steps_until(seen, 1, healthy, 5) <= NOTICED_WITHIN_STEPS
    finally:
        os.kill(pid, signal.SIGCONT)
    rig.driver.end(1, True)
    rig.wait_healthy(name)

    # 2. SIGKILL (dead): noticed within 3 steps.
    rig.start(2)
    rig.run_paced(2, healthy, range(5))
    seen = noticed(2)
    os.kill(rig.launch.pid_of(name), signal.SIGKILL)
    assert rig.steps_until(seen, 2, healthy, 5) <= NOTICED_WITHIN_STEPS
    assert rig.spin_until(lambda: len(rig.launch.pids_of(name)) == 2, timeout=30), "\n".join(rig.launch.lines[-20:])
    rig.driver.end(2, True)

    # 3. respawned by the launcher: the calibration is reloaded and the next rollouts are judged normally.
    rig.wait_healthy(name)
    assert any(f"respawning {name}" in line for line in rig.launch.lines)
    rig.start(3)
    ok = rig.run_paced(3, healthy, range(LENGTH))
    assert [ok[t].state for t in range(LENGTH)] == [FailureAlarm.STATE_OK] * LENGTH
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
