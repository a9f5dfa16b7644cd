"""Small rotation helpers (MuJoCo quaternions are w, x, y, z)."""
from __future__ import annotations

import mujoco
import numpy as np


def yaw_quat(yaw: float) -> np.ndarray:
    """Quaternion of a rotation by ``yaw`` radians about the world z axis."""
    return np.array([np.cos(yaw / 2.0), 0.0, 0.0, np.sin(yaw / 2.0)])


def quat_yaw(quat: np.ndarray) -> float:
    """Yaw angle (rotation about z) of a quaternion, assuming it is close to a pure yaw rotation."""
    w, x, y, z = quat
    return float(np.arctan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z)))


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle (or array of angles) to [-pi, pi)."""
    return (np.asarray(angle) + np.pi) % (2.0 * np.pi) - np.pi


def camera_quat(view_dir: np.ndarray, up_hint: np.ndarray) -> np.ndarray:
    """Quaternion of a MuJoCo camera frame looking along ``view_dir`` with image-up close to ``up_hint``.

    MuJoCo cameras look along their local -z axis with +y pointing up in the image.
    """
    z_axis = -np.asarray(view_dir, dtype=float)
    z_axis /= np.linalg.norm(z_axis)
    x_axis = np.cross(np.asarray(up_hint, dtype=float), z_axis)
    x_axis /= np.linalg.norm(x_axis)
    y_axis = np.cross(z_axis, x_axis)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.column_stack([x_axis, y_axis, z_axis]).ravel())
    return quat


def hand_down_quat(yaw: float) -> np.ndarray:
    """World orientation of the Panda hand pointing straight down, rotated by ``yaw`` about world z.

    The hand's z axis (towards the fingers) points along world -z; at ``yaw = 0`` the hand's x axis is
    world +x and the fingers open along world y.
    """
    down = np.array([0.0, 1.0, 0.0, 0.0])  # 180 degrees about x
    quat = np.zeros(4)
    mujoco.mju_mulQuat(quat, yaw_quat(yaw), down)
    return quat
