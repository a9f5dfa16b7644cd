"""Joint-velocity ACE over DDS: a batch waits for the joint state of its stamp, whatever arrives first."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.context import Context
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from sensor_msgs.msg import JointState
from sim_bridge.robot import URDF_PATH

from fiper_msgs.msg import ActionChunkBatch, RolloutEvent, Score
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.kinematics import PinocchioFK
from fiper_ros.core.monitor import DetectorMonitor
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import action_batch_msg, rollout_event_msg, to_stamp
from fiper_ros.nodes.ace_node import AceNode
from helpers.spin import spin_until

CALIBRATION = Path(__file__).resolve().parents[2] / "models" / "stacking" / "calibration"
MS = 1_000_000
#: Longest wait for a joint state: generous, so that case 1 never runs out of it on a loaded machine.
WAIT_S = 3.0


def _joint_state(stamp: int, q: np.ndarray) -> JointState:
    msg = JointState(name=[f"panda_joint{i}" for i in range(1, 8)], position=[float(v) for v in q])
    msg.header.stamp = to_stamp(stamp)
    return msg


def test_a_batch_is_scored_from_the_joint_state_of_its_stamp_even_if_that_arrives_later(ros_domain: int) -> None:
    context = Context()
    rclpy.init(context=context, domain_id=ros_domain)
    executor = SingleThreadedExecutor(context=context)
    ace = AceNode(context=context, namespace="/fiper", parameter_overrides=[
        Parameter("calibration_dir", value=str(CALIBRATION)), Parameter("urdf_path", value=str(URDF_PATH)),
        Parameter("joint_state_wait_s", value=WAIT_S), Parameter("diagnostics_period_s", value=0.1)])
    driver = rclpy.create_node("driver", namespace="/fiper", context=context)
    batches = driver.create_publisher(ActionChunkBatch, "action_chunks", qos.INPUT)
    events = driver.create_publisher(RolloutEvent, "rollout_events", qos.EVENT)
    joints = driver.create_publisher(JointState, "/joint_states", qos.INPUT)
    scores: dict[tuple[int, int], Score] = {}
    driver.create_subscription(Score, "scores/ace", lambda m: scores.setdefault((m.rollout_id, m.step), m),
                               qos.SCORE_SUB)
    waiting: list[str] = []  # the ACE node's waiting_for_joint_state, report by report
    driver.create_subscription(DiagnosticArray, "/diagnostics", lambda m: waiting.extend(
        kv.value for status in m.status if status.name.endswith("/ace_node")
        for kv in status.values if kv.key == "waiting_for_joint_state"), qos.DIAGNOSTICS)
    for node in (ace, driver):
        executor.add_node(node)

    def spin(condition, timeout: float = 10.0) -> bool:  # noqa: ANN001
        return spin_until(executor, condition, timeout, step=0.02)

    calibration = load_calibration(CALIBRATION)
    monitor = DetectorMonitor(calibration, "ace", "stacking", PinocchioFK(URDF_PATH, "panda_hand"))
    rng = np.random.default_rng(0)
    velocities = [rng.normal(0.0, 0.3, (8, calibration.layout.horizon, calibration.layout.action_dim)).astype(np.float32)
                  for _ in range(3)]
    q = [np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8]) + 0.05 * i for i in range(4)]
    try:
        assert spin(lambda: ace.lifecycle_state() == "active" and joints.get_subscription_count() >= 1
                    and batches.get_subscription_count() >= 1 and events.get_subscription_count() >= 1)
        events.publish(rollout_event_msg(7, RolloutEvent.EVENT_START, 0, task="stacking"))
        joints.publish(_joint_state(100 * MS, q[0]))
        assert spin(lambda: ace._joints.latest_stamp == 100 * MS)

        # 1. the batch of 200 ms comes before the joint state of 200 ms: it waits, then uses that state
        batches.publish(action_batch_msg(7, 0, 200 * MS, velocities[0], 4, "joint_velocity"))
        assert spin(lambda: len(ace._gate) == 1)
        # Three reports of the node saying the batch waits (one in flight may still say 0, from before it
        # came): it stayed held over two diagnostics periods while the gate's 50 ms timer ran, and no
        # report after the first of them says it was released without its joint state.
        reports = len(waiting)
        assert spin(lambda: waiting[reports:].count("1") >= 3)
        held = waiting[reports:][waiting[reports:].index("1"):]
        assert "0" not in held and (7, 0) not in scores
        joints.publish(_joint_state(200 * MS, q[1]))
        assert spin(lambda: (7, 0) in scores)
        assert scores[7, 0].score == np.float32(monitor.update(0, (velocities[0], q[1])).score)

        # 2. an END behind a waiting batch waits too, so the batch still belongs to its rollout
        batches.publish(action_batch_msg(7, 1, 300 * MS, velocities[1], 4, "joint_velocity"))
        assert spin(lambda: len(ace._gate) == 1)
        events.publish(rollout_event_msg(7, RolloutEvent.EVENT_END, 0, outcome=RolloutEvent.OUTCOME_SUCCESS))
        assert spin(lambda: len(ace._gate) == 2)
        joints.publish(_joint_state(400 * MS, q[2]))  # a later control step's state opens the gate
        assert spin(lambda: (7, 1) in scores and ace.gate.active is None)
        assert scores[7, 1].score == np.float32(monitor.update(1, (velocities[1], q[1])).score)  # latest <= 300 ms

        # 3. no joint state at or after the stamp: after joint_state_wait_s the latest one before it is used
        events.publish(rollout_event_msg(8, RolloutEvent.EVENT_START, 0, task="stacking"))
        assert spin(lambda: ace.gate.active is not None and ace.gate.active.rollout_id == 8)
        batches.publish(action_batch_msg(8, 0, 500 * MS, velocities[2], 4, "joint_velocity"))
        assert spin(lambda: (8, 0) in scores)
        assert ace.joint_state_waits_out == 1
        assert scores[8, 0].score == np.float32(monitor.update(2, (velocities[2], q[2])).score)  # latest <= 500 ms
        assert not ace.rejected, ace.rejected
    finally:
        executor.shutdown()
        ace.destroy_node()
        driver.destroy_node()
        rclpy.try_shutdown(context=context)
