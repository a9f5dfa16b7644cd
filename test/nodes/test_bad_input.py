"""Every class of bad input is rejected, counted on /diagnostics, never reported OK, and survived."""
from __future__ import annotations

import array
from pathlib import Path

import numpy as np
from rclpy.parameter import Parameter
from rclpy.serialization import serialize_message

from fiper_msgs.msg import FailureAlarm
from fiper_ros.interface.conversions import action_batch_msg, embedding_msg
from helpers.suite import STEP_NS, Suite
from helpers.synthetic import E, make_rollout


def _rejected(suite: Suite, node: str, reason: str) -> int:
    values = suite.driver.diagnostics.get(f"fiper: /fiper/{node}", {})
    return int(values.get(f"rejected.{reason}", 0))


def _wait_rejected(suite: Suite, node: str, reason: str, count: int = 1) -> None:
    assert suite.spin_until(lambda: _rejected(suite, node, reason) >= count, timeout=5.0), (
        node, reason, suite.driver.diagnostics.get(f"fiper: /fiper/{node}"))


def test_each_bad_input_class_is_rejected_and_the_node_keeps_scoring(ros_domain: int, calibration_dir: Path) -> None:
    suite = Suite(ros_domain, str(calibration_dir), extra=[Parameter("max_elements", value=1000),
                                                            Parameter("diagnostics_period_s", value=0.1)])
    try:
        suite.wait_active()
        rollout = make_rollout(400)
        drv = suite.driver
        emb, act, h = rollout.embeddings, rollout.actions, rollout.exec_steps

        # A message of a rollout nobody started.
        drv.embeddings.publish(embedding_msg(77, 0, STEP_NS, emb[0]))
        _wait_rejected(suite, "rnd_oe_node", "unknown_rollout")

        drv.start(1)
        suite.spin_until(lambda: suite.fusion.fuser.rollout_id == 1)
        drv.step(1, 0, emb[0], act[0], h)
        assert suite.spin_until(lambda: 0 in drv.alarms_of(1))

        def send(step: int, embedding: object, batch: object) -> None:
            drv.embeddings.publish(embedding)
            drv.batches.publish(batch)

        def good_emb(step: int) -> object:
            return embedding_msg(1, step, (step + 1) * STEP_NS, emb[step])

        def batch(step: int, actions: np.ndarray, space: str = "ee_position") -> object:
            return action_batch_msg(1, step, (step + 1) * STEP_NS, actions, h, space)

        nan_emb = emb[1].copy()
        nan_emb[3] = np.nan
        send(1, embedding_msg(1, 1, 2 * STEP_NS, nan_emb), batch(1, act[1]))
        _wait_rejected(suite, "rnd_oe_node", "non_finite")
        wrong_shape = good_emb(2)
        wrong_shape.shape = [E + 1]
        short = batch(2, act[2])
        short.data = array.array("f", short.data[:-1])
        send(2, wrong_shape, short)
        _wait_rejected(suite, "rnd_oe_node", "shape")
        _wait_rejected(suite, "ace_node", "shape")
        send(3, embedding_msg(1, 3, 4 * STEP_NS, np.zeros(E + 1, np.float32)), batch(3, np.zeros((32, 8, 3), np.float32)))
        _wait_rejected(suite, "rnd_oe_node", "calibration_mismatch")
        _wait_rejected(suite, "ace_node", "calibration_mismatch")
        send(4, good_emb(4), batch(4, act[4], "joint_velocity"))
        _wait_rejected(suite, "ace_node", "action_space")
        inf_act = act[5].copy()
        inf_act[0, 0, 0] = np.inf
        send(5, good_emb(5), batch(5, inf_act))
        _wait_rejected(suite, "ace_node", "non_finite")
        send(6, embedding_msg(1, 6, 7 * STEP_NS, nan_emb), batch(6, np.zeros((100, 8, 2), np.float32)))
        _wait_rejected(suite, "ace_node", "oversize")
        _wait_rejected(suite, "rnd_oe_node", "non_finite", 2)
        drv.embeddings.publish(good_emb(6))
        _wait_rejected(suite, "rnd_oe_node", "duplicate_step")
        drv.batches.publish(batch(0, act[0]))
        _wait_rejected(suite, "ace_node", "out_of_order_step")
        # Bytes that are no message of the topic's type: the nodes read the CDR bytes themselves (issue #24).
        # No step can be read from them, so no step is marked missing.
        drv.embeddings.publish(serialize_message(good_emb(7))[:-9])
        drv.batches.publish(serialize_message(batch(7, act[7]))[:100])
        _wait_rejected(suite, "rnd_oe_node", "malformed")
        _wait_rejected(suite, "ace_node", "malformed")

        # The suite still scores good steps; the broken steps are never reported OK.
        for step in range(7, 11):
            drv.step(1, step, emb[step], act[step], h)
            assert suite.spin_until(lambda s=step: any(m.step == s and m.rollout_id == 1 for m in drv.alarms)), step
        per_step = drv.alarms_of(1)
        assert per_step[0].state == FailureAlarm.STATE_OK
        # Each of steps 1-6 had at least one input rejected: its verdict is said aloud, and it is UNKNOWN.
        for step in range(1, 7):
            assert per_step[step].state == FailureAlarm.STATE_UNKNOWN, per_step[step]
            assert "input of this step rejected" in per_step[step].reason, per_step[step]
        # w = 3: the windows of steps 7 and 8 still hold missing steps of both detectors.
        for step in (7, 8):
            assert per_step[step].state == FailureAlarm.STATE_UNKNOWN, per_step[step]
            assert "missing step" in per_step[step].reason
        assert per_step[9].state == FailureAlarm.STATE_OK and per_step[10].state == FailureAlarm.STATE_OK
        assert suite.rnd_oe.lifecycle_state() == "active" and suite.ace.lifecycle_state() == "active"
    finally:
        suite.close()


def test_missing_calibration_keeps_nodes_alive_and_the_alarm_unknown(ros_domain: int, tmp_path: Path) -> None:
    suite = Suite(ros_domain, str(tmp_path / "does-not-exist"), fusion=[Parameter("deadline_s", value=0.5)])
    try:
        assert suite.spin_until(lambda: "fiper: /fiper/rnd_oe_node" in suite.driver.diagnostics)
        diag = suite.driver.diagnostics["fiper: /fiper/rnd_oe_node"]
        assert "calibration directory not found" in diag["message"] and diag["lifecycle_state"] == "unconfigured"
        assert suite.spin_until(lambda: suite.fusion.lifecycle_state() == "active")
        suite.driver.start(3)
        rollout = make_rollout(401)
        suite.driver.step(3, 0, rollout.embeddings[0], rollout.actions[0], rollout.exec_steps)
        assert suite.spin_until(lambda: any(m.rollout_id == 3 and "missing or older" in m.reason
                                            for m in suite.driver.alarms), timeout=5.0)
        assert all(m.state != FailureAlarm.STATE_OK for m in suite.driver.alarms)
    finally:
        suite.close()
