"""Operational-space layer: damped-least-squares differential inverse kinematics of the Panda TCP.

The solver works on its own ``MjData`` (kinematics only), so it never disturbs the simulation. Tasks
with end-effector actions turn each EE target into arm joint targets for the position servos.
"""
from __future__ import annotations

import mujoco
import numpy as np

from .robot import ARM_JOINTS, HOME_QPOS, TCP_SITE

_DAMPING = 1e-3
_MAX_JOINT_STEP = 0.25
_NULLSPACE_GAIN = 0.05
_ROT_WEIGHT = 0.5


class DiffIK:
    """Differential IK for the TCP site's position and orientation over the seven arm joints."""

    def __init__(self, model: mujoco.MjModel) -> None:
        """Create a solver for ``model``, which must contain the Panda built by ``robot.panda_spec``."""
        self._model = model
        self._data = mujoco.MjData(model)
        self._site = model.site(TCP_SITE).id
        self._qpos_idx = np.array([model.joint(name).qposadr[0] for name in ARM_JOINTS])
        self._dof_idx = np.array([model.joint(name).dofadr[0] for name in ARM_JOINTS])
        self._lower = np.array([model.joint(name).range[0] for name in ARM_JOINTS])
        self._upper = np.array([model.joint(name).range[1] for name in ARM_JOINTS])
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))

    def forward(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Return the TCP position and quaternion for arm joint positions ``q``."""
        self._data.qpos[self._qpos_idx] = q
        mujoco.mj_kinematics(self._model, self._data)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, self._data.site_xmat[self._site])
        return self._data.site_xpos[self._site].copy(), quat

    def solve(
        self, q_init: np.ndarray, pos: np.ndarray, quat: np.ndarray, iterations: int = 4
    ) -> np.ndarray:
        """Return arm joint positions moving the TCP towards ``pos`` / ``quat``.

        Args:
            q_init: Seed joint positions (7,), e.g. the previous solution.
            pos: Target TCP position (3,) in the world frame.
            quat: Target TCP orientation (w, x, y, z).
            iterations: Newton steps; a few suffice when warm-started from the last control step.
        """
        q = np.array(q_init, dtype=float)
        err = np.zeros(6)
        cur_quat = np.zeros(4)
        for _ in range(iterations):
            self._data.qpos[self._qpos_idx] = q
            mujoco.mj_kinematics(self._model, self._data)
            mujoco.mj_comPos(self._model, self._data)
            err[:3] = pos - self._data.site_xpos[self._site]
            mujoco.mju_mat2Quat(cur_quat, self._data.site_xmat[self._site])
            mujoco.mju_subQuat(err[3:], quat, cur_quat)  # rotation vector in the TCP frame
            err[3:] = _ROT_WEIGHT * self._data.site_xmat[self._site].reshape(3, 3) @ err[3:]
            mujoco.mj_jacSite(self._model, self._data, self._jacp, self._jacr, self._site)
            jac = np.vstack([self._jacp[:, self._dof_idx], _ROT_WEIGHT * self._jacr[:, self._dof_idx]])
            jjt = jac @ jac.T + _DAMPING * np.eye(6)
            dq = jac.T @ np.linalg.solve(jjt, err)
            null = np.eye(7) - jac.T @ np.linalg.solve(jjt, jac)
            dq += null @ (_NULLSPACE_GAIN * (HOME_QPOS - q))
            q = np.clip(q + np.clip(dq, -_MAX_JOINT_STEP, _MAX_JOINT_STEP), self._lower, self._upper)
        return q
