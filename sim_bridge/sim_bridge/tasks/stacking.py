"""Stacking-1: grasp one of three blocks and place it in the target area.

Actions (D = 8): seven arm joint velocities [rad/s] (integrated into the joint position targets) and
the gripper opening in [0, 1] (0 closed, 1 open). Success: a block rests inside the target area with
the gripper opened wider than the block. A block falling off the table is a failure.
H = 8, h = 4, 120 policy steps at 10 Hz.
"""
from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from ..robot import FINGER_MAX, HOME_QPOS
from ..scene import add_box_body, add_patch
from ..transforms import hand_down_quat, quat_yaw, yaw_quat
from .base import OFF_TABLE_Z, TaskEnv

COLORS: tuple[str, ...] = ("red", "green", "blue")
BLOCK_HALF = 0.02
BLOCK_MASS = 0.1
BLOCK_X = (0.38, 0.58)
BLOCK_Y = (-0.2, 0.2)
MIN_SEPARATION = 0.1
"""Smallest distance between block centres at ID size [m]; it grows with the block scale so that the
open fingers fit between neighbouring blocks."""
TARGET_CENTER = (0.45, -0.33)
TARGET_HALF = 0.06
TARGET_JITTER = 0.02
START_TCP = (0.35, 0.0, 0.2)
MAX_JOINT_VEL = 1.5
"""Joint velocity actions are clipped to +-MAX_JOINT_VEL [rad/s]."""
_RGBA = {"red": (0.85, 0.12, 0.12, 1.0), "green": (0.15, 0.7, 0.2, 1.0), "blue": (0.12, 0.28, 0.85, 1.0)}
_TARGET_RGBA = (0.95, 0.85, 0.3, 1.0)


class StackingEnv(TaskEnv):
    """Stacking-1 task (see module docstring). Proprio: TCP position (3), gripper width (1), arm joints (7)."""

    name = "stacking"
    action_dim = 8
    proprio_dim = 11
    horizon = 8
    exec_steps = 4
    max_policy_steps = 120

    def _sample_layout(self, rng: np.random.Generator) -> None:
        self.block_half = BLOCK_HALF * self.knobs["block_scale"]
        self.target = (
            np.array(TARGET_CENTER) + [0.0, self.knobs["target_shift"]] + rng.uniform(-TARGET_JITTER, TARGET_JITTER, 2)
        )
        blocks: list[np.ndarray] = []
        while len(blocks) < len(COLORS):
            candidate = np.array([rng.uniform(*BLOCK_X), rng.uniform(*BLOCK_Y)])
            if all(np.linalg.norm(candidate - b) >= MIN_SEPARATION * self.knobs["block_scale"] for b in blocks):
                blocks.append(candidate)
        self.block_start = dict(zip(COLORS, blocks))
        self.block_yaw = {c: float(rng.uniform(-np.pi / 4, np.pi / 4)) for c in COLORS}

    def _add_objects(self, spec: mujoco.MjSpec) -> None:
        add_patch(spec, "target", tuple(self.target), (TARGET_HALF, TARGET_HALF), _TARGET_RGBA)
        mass = BLOCK_MASS * self.knobs["mass_scale"] * self.knobs["block_scale"] ** 3
        for c in COLORS:
            add_box_body(
                spec, f"block_{c}", (self.block_half,) * 3, (*self.block_start[c], self.block_half),
                self.block_yaw[c], _RGBA[c], mass, self.knobs["friction"],
            )

    def _initial_arm(self) -> tuple[np.ndarray, float]:
        q = self.ik.solve(HOME_QPOS, np.array(START_TCP), hand_down_quat(0.0), iterations=100)
        return q, FINGER_MAX

    def _place_objects(self) -> None:
        for c in COLORS:
            self.set_free_pose(
                f"block_{c}", np.array([*self.block_start[c], self.block_half]), yaw_quat(self.block_yaw[c])
            )

    def _apply_action(self, action: np.ndarray) -> None:
        qdot = np.clip(action[:7], -MAX_JOINT_VEL, MAX_JOINT_VEL)
        low, high = self.model.actuator_ctrlrange[self._arm_act].T
        self.q_cmd = np.clip(self.q_cmd + qdot / self.control_hz, low, high)
        self.set_gripper(action[7])

    def placed(self, color: str) -> bool:
        """Whether the ``color`` block rests inside the target area and the gripper has let go of it."""
        pos, _ = self.free_pose(f"block_{color}")
        return bool(
            np.all(np.abs(pos[:2] - self.target) <= TARGET_HALF)
            and 0.0 < pos[2] <= self.block_half + 0.01
            and self.gripper_width() > 2.0 * self.block_half + 0.004
        )

    def _evaluate(self) -> tuple[bool, bool]:
        off_table = any(self.free_pose(f"block_{c}")[0][2] < OFF_TABLE_Z for c in COLORS)
        return any(self.placed(c) for c in COLORS) and not off_table, off_table

    def _proprio(self) -> np.ndarray:
        return np.concatenate([self.tcp_pos(), [self.gripper_width()], self.arm_qpos()])

    def state(self) -> dict[str, Any]:
        blocks = {}
        for c in COLORS:
            pos, quat = self.free_pose(f"block_{c}")
            blocks[c] = {"pos": pos, "yaw": quat_yaw(quat)}
        return {
            "tcp": self.tcp_pos(),
            "q_cmd": self.q_cmd.copy(),
            "gripper_width": self.gripper_width(),
            "blocks": blocks,
            "target": self.target.copy(),
            "block_half": self.block_half,
            "target_half": TARGET_HALF,
        }
