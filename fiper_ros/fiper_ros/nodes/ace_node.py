"""ACE node: ActionChunkBatch -> Score on ``scores/ace`` (paper eqs. 4-6); the detector node's preset.

Joint-space batches are mapped to end-effector positions with pinocchio (parameters ``urdf_path``
and ``ee_frame``); joint-velocity batches are integrated first from the ``joint_states`` position
with the latest stamp not after the batch's (:mod:`fiper_ros.runtime.joint_history`). In that mode
batches and rollout events pass a :class:`~fiper_ros.runtime.joint_history.StampGate` in arrival order:
a batch is scored once a joint state stamped at or after it has arrived, or ``joint_state_wait_s`` passed.
"""
from __future__ import annotations

import sys
from collections.abc import Mapping
from typing import Any

import numpy as np
from sensor_msgs.msg import JointState

from fiper_msgs.msg import ActionChunkBatch, RolloutEvent
from fiper_ros.core.calibration import Calibration
from fiper_ros.core.detectors import ACE
from fiper_ros.core.kinematics import ForwardKinematics, PinocchioFK
from fiper_ros.interface import qos
from fiper_ros.interface.conversions import stamp_ns
from fiper_ros.interface.topics import ARM_JOINT_NAMES, JOINT_STATES_TOPIC
from fiper_ros.nodes.base import describe
from fiper_ros.nodes.detector_node import DetectorNode
from fiper_ros.nodes.errors import NodeError
from fiper_ros.nodes.settings import AceSettings, ace_settings
from fiper_ros.platform.process import EXECUTOR_EVENTS, run_node, run_reported
from fiper_ros.runtime import validation
from fiper_ros.runtime.joint_history import JointHistory, StampGate
from fiper_ros.runtime.validation import InputRejected

JOINT_SPACES = (ActionChunkBatch.ACTION_SPACE_JOINT_POSITION, ActionChunkBatch.ACTION_SPACE_JOINT_VELOCITY)


class AceNode(DetectorNode):
    """Scores each batch of sampled action chunks with action-chunk entropy."""

    preset = ACE

    settings: AceSettings

    def __init__(self, **kwargs: Any) -> None:
        self._joints = JointHistory()
        self._joint_sub: Any = None
        self._gate_timer: Any = None
        #: Batches scored after joint_state_wait_s without a joint state at or after their stamp.
        self.joint_state_waits_out = 0
        super().__init__("ace_node", **kwargs)
        if self.settings is not None:
            self._gate = StampGate(self.settings.joint_state_wait_ns)

    def declare_preset_parameters(self) -> None:
        """The robot's parameters."""
        self.declare_parameter("urdf_path", "", describe("robot URDF for joint-space actions", read_only=True))
        self.declare_parameter("ee_frame", "panda_hand", describe("end-effector frame of the URDF", read_only=True))
        self.declare_parameter("joint_state_topic", JOINT_STATES_TOPIC,
                               describe("measured joint positions, for joint-velocity actions", read_only=True))
        self.declare_parameter("joint_names", list(ARM_JOINT_NAMES),
                               describe("joints of the URDF chain, picked by name from joint_states", read_only=True))
        self.declare_parameter("joint_state_wait_s", 0.5,
                               describe("longest wait of a joint-velocity batch for the joint state of its stamp",
                                        read_only=True, low=0.0, high=10.0))

    @staticmethod
    def build_settings(values: Mapping[str, Any]) -> AceSettings:
        """The node's settings from its parameters' values (:func:`~fiper_ros.nodes.settings.ace_settings`)."""
        return ace_settings(values)

    def forward_kinematics(self, calibration: Calibration) -> ForwardKinematics | None:
        """The robot's FK for joint-space actions (parameters ``urdf_path``, ``ee_frame``)."""
        if calibration.layout.action_space not in JOINT_SPACES:
            return None
        if not self.settings.urdf_path:
            raise NodeError(f"calibration action space is {calibration.layout.action_space}: set parameter urdf_path")
        return PinocchioFK(self.settings.urdf_path, self.settings.ee_frame)

    def activate(self) -> None:
        super().activate()
        if self.calibration is not None and \
                self.calibration.layout.action_space == ActionChunkBatch.ACTION_SPACE_JOINT_VELOCITY:
            self._joint_sub = self.create_subscription(
                JointState, self.settings.joint_state_topic, self._on_joint_state, qos.INPUT)
            self._inputs.append(self._joint_sub)
            self._gate_timer = self.create_timer(0.05, self._release, clock=self.steady)

    def deactivate(self) -> None:
        self._release(force=True)
        if self._gate_timer is not None:
            self.destroy_timer(self._gate_timer)
            self._gate_timer = None
        self._joint_sub = None
        super().deactivate()

    def _on_input(self, msg: ActionChunkBatch) -> None:
        if self._joint_sub is None:
            super()._on_input(msg)
            return
        self._gate.push(super()._on_input, msg, stamp_ns(msg.header.stamp), self.steady.now().nanoseconds)
        self._release()

    def _on_event(self, msg: RolloutEvent) -> None:
        if len(self._gate) == 0:
            super()._on_event(msg)
            return
        self._gate.push(super()._on_event, msg, None, self.steady.now().nanoseconds)

    def _on_joint_state(self, msg: JointState) -> None:
        if msg.position and len(msg.position) != len(msg.name):  # sensor_msgs: one position per name, or none
            self.reject(InputRejected(validation.SHAPE, f"joint state of {len(msg.name)} names and "
                                                        f"{len(msg.position)} positions"))
            return
        positions = dict(zip(msg.name, msg.position))
        names = self.settings.joint_names
        if all(name in positions for name in names):
            try:
                q = validation.vector([positions[name] for name in names], len(names), "joint state",
                                      self.settings.max_abs_value, np.float64)
            except InputRejected as error:
                self.reject(error)
                return
            self._joints.add(stamp_ns(msg.header.stamp), q)
            self._release()

    def _release(self, force: bool = False) -> None:
        now = self.steady.now().nanoseconds + (self._gate.wait_ns if force else 0)
        for handler, item, waited_out in self._gate.release(self._joints.latest_stamp, now):
            if waited_out:
                self.joint_state_waits_out += 1
                self.get_logger().warning(
                    f"batch of rollout {item.rollout_id} step {item.step}: no joint state at or after its stamp "
                    f"within joint_state_wait_s; integrating from the latest one before it")
            handler(item)

    def to_value(self, msg: ActionChunkBatch) -> tuple[np.ndarray, np.ndarray | None]:
        """The batch and, for joint velocities, the joint position it integrates from."""
        actions = self.batch(msg)
        if self.calibration.layout.action_space != ActionChunkBatch.ACTION_SPACE_JOINT_VELOCITY:
            return actions, None
        q_current = self._joints.at(stamp_ns(msg.header.stamp))
        if q_current is None:
            raise InputRejected(validation.NO_JOINT_STATE, "joint-velocity actions need a joint_states message "
                                                           "stamped at or before the batch")
        return actions, q_current

    def diagnostic_values(self) -> dict[str, str]:
        if self.settings is None:
            return {}
        return super().diagnostic_values() | {"waiting_for_joint_state": str(len(self._gate)),
                                              "joint_state_waits_out": str(self.joint_state_waits_out)}


#: The node class, for in-process launching.
NODE_CLASS = AceNode


def main(args: list[str] | None = None) -> int:
    """Entry point: ``python -m fiper_ros.nodes.ace_node --ros-args ...``."""
    return run_reported("ace_node", run_node, AceNode, args, executor=EXECUTOR_EVENTS)


if __name__ == "__main__":
    sys.exit(main())
