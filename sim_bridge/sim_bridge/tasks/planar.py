"""Planar end-effector control shared by the pushing tasks (Sorting, PushT).

An action is the target (x, y) of the TCP in the world frame; the TCP height and the hand orientation
(pointing down, fingers closed) are fixed. Targets are clipped to the reachable workspace and the
commanded TCP moves at most ``MAX_EE_STEP`` per control step towards them; the IK layer turns the
commanded TCP pose into joint targets for the position servos.
"""
from __future__ import annotations

import abc

import numpy as np

from ..robot import HOME_QPOS
from ..transforms import hand_down_quat
from .base import TaskEnv

PUSH_HEIGHT = 0.02
"""TCP height during pushing [m]: the finger pads' lower edge is about 1 cm above the table."""
WORKSPACE_X = (0.25, 0.78)
WORKSPACE_Y = (-0.42, 0.42)
MAX_REACH = 0.78
"""Largest horizontal distance of the TCP from the robot base [m]."""
MAX_EE_STEP = 0.04
"""Largest TCP displacement commanded per control step [m] (0.4 m/s at 10 Hz)."""
HAND_QUAT = hand_down_quat(0.0)


def clip_to_workspace(xy: np.ndarray) -> np.ndarray:
    """Clip a planar TCP target to the workspace box and reach circle."""
    clipped = np.array([np.clip(xy[0], *WORKSPACE_X), np.clip(xy[1], *WORKSPACE_Y)])
    radius = np.linalg.norm(clipped)
    return clipped * (MAX_REACH / radius) if radius > MAX_REACH else clipped


def in_workspace(xy: np.ndarray) -> bool:
    """Whether a planar TCP target lies inside the workspace (clipping would not move it)."""
    return bool(np.linalg.norm(clip_to_workspace(xy) - xy) <= 1e-9)


class PlanarPushEnv(TaskEnv, abc.ABC):
    """Task with planar TCP-position actions (D = 2) and a closed gripper used as the pusher.

    Proprio: TCP position (3) and gripper width (1).
    """

    action_dim = 2
    proprio_dim = 4

    @abc.abstractmethod
    def _start_xy(self) -> np.ndarray:
        """Initial planar TCP position of the episode."""

    def _initial_arm(self) -> tuple[np.ndarray, float]:
        self.ee_cmd = clip_to_workspace(self._start_xy())
        q = self.ik.solve(HOME_QPOS, np.array([*self.ee_cmd, PUSH_HEIGHT]), HAND_QUAT, iterations=100)
        return q, 0.0

    def _apply_action(self, action: np.ndarray) -> None:
        delta = clip_to_workspace(action) - self.ee_cmd
        norm = np.linalg.norm(delta)
        if norm > MAX_EE_STEP:
            delta *= MAX_EE_STEP / norm
        self.ee_cmd = self.ee_cmd + delta
        self.q_cmd = self.ik.solve(self.q_cmd, np.array([*self.ee_cmd, PUSH_HEIGHT]), HAND_QUAT)
        self.set_gripper(0.0)

    def _proprio(self) -> np.ndarray:
        return np.concatenate([self.tcp_pos(), [self.gripper_width()]])
