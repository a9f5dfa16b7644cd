"""Scripted Stacking-1 expert: pick the red block and place it in the target area.

The expert always takes the same block colour (``BLOCK``), so the choice is visible in the cameras. An
earlier version drew the block from the seed; a policy cloned from it could not tell which block to
take and descended between blocks (ID success 0.06, docs/policies.md).

The expert tracks a sequence of TCP waypoints (above the block, grasp height, lift, above the target,
place height, lift) with the hand pointing down. A Cartesian reference moves towards the active
waypoint at bounded speed; differential IK turns it into joint positions and the action is the joint
velocity reaching them in one control step.

The hand's yaw turns to the block's faces at a bounded rate (``YAW_STEP``) and the expert descends
only once it is aligned, so the turn spans several policy steps and every demonstrated state shows the
turn still left to do. An earlier expert turned the hand as fast as the joint limits allowed, within
the first policy step; a policy cloned from it turned its hand once, too little at large block yaws,
and never corrected it (docs/policies.md).
"""
from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from ..ik import DiffIK
from ..planar import step_towards
from ..tasks.stacking import COLORS, MAX_JOINT_VEL
from ..transforms import hand_down_quat, wrap_angle

CARRY_HEIGHT = 0.12
CART_STEP = 0.02
"""Largest reference TCP displacement per control step [m]."""
REACHED = 0.008
YAW_STEP = float(np.radians(3.0))
"""Largest change of the hand's yaw reference per control step [rad]."""
GRIP_WAIT = 6
RELEASE_WAIT = 5
LAST_PHASE = 7
BLOCK = COLORS[0]
"""The block the expert carries (red)."""


class StackingExpert:
    """Privileged-state expert of the Stacking-1 task; ``act(state)`` returns the next 8-D action."""

    def __init__(self, model: mujoco.MjModel, control_hz: float) -> None:
        """``model`` is the environment's model (for IK)."""
        self._ik = DiffIK(model)
        self._hz = control_hz
        self._phase = 0
        self._wait = 0
        self._ref: np.ndarray | None = None
        self._yaw = 0.0
        self._target_yaw = 0.0
        self._grasp_xy: np.ndarray | None = None

    def _waypoint(self, state: dict[str, Any]) -> tuple[np.ndarray | None, float]:
        """Active waypoint (None while waiting) and gripper opening of the current phase."""
        if self._phase < 2:
            self._grasp_xy = state["blocks"][BLOCK]["pos"][:2].copy()
        block = self._grasp_xy
        target = state["target"]
        grasp_z = max(state["block_half"], 0.018)
        phases = [
            (np.array([block[0], block[1], CARRY_HEIGHT]), 1.0),
            (np.array([block[0], block[1], grasp_z]), 1.0),
            (None, 0.0),
            (np.array([block[0], block[1], CARRY_HEIGHT]), 0.0),
            (np.array([target[0], target[1], CARRY_HEIGHT]), 0.0),
            (np.array([target[0], target[1], state["block_half"] + 0.008]), 0.0),
            (None, 1.0),
            (np.array([target[0], target[1], CARRY_HEIGHT]), 1.0),
        ]
        return phases[self._phase]

    def act(self, state: dict[str, Any]) -> np.ndarray:
        """Next action for the privileged ``state`` of ``StackingEnv.state()``."""
        if self._ref is None:
            self._ref = state["tcp"].copy()
        if self._phase < 2:
            # The block's face direction nearest the hand's (blocks are symmetric under quarter turns).
            block_yaw = state["blocks"][BLOCK]["yaw"]
            self._target_yaw = self._yaw + float(wrap_angle(4.0 * (block_yaw - self._yaw)) / 4.0)
        self._yaw += float(np.clip(self._target_yaw - self._yaw, -YAW_STEP, YAW_STEP))
        aligned = abs(self._target_yaw - self._yaw) < 1e-6
        waypoint, gripper = self._waypoint(state)
        if waypoint is None:
            self._wait += 1
            if self._wait >= (GRIP_WAIT if gripper == 0.0 else RELEASE_WAIT):
                self._phase, self._wait = min(self._phase + 1, LAST_PHASE), 0
        else:
            self._ref = step_towards(self._ref, waypoint, CART_STEP)
            if np.linalg.norm(state["tcp"] - waypoint) < REACHED and (self._phase > 0 or aligned):
                self._phase = min(self._phase + 1, LAST_PHASE)
        q_des = self._ik.solve(state["q_cmd"], self._ref, hand_down_quat(self._yaw), iterations=8)
        qdot = np.clip((q_des - state["q_cmd"]) * self._hz, -MAX_JOINT_VEL, MAX_JOINT_VEL)
        return np.concatenate([qdot, [gripper]])
