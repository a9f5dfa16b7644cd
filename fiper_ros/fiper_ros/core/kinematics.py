"""End-effector positions for ACE (App. A.1, last paragraph).

The paper computes ACE on predicted end-effector (EE) positions in Cartesian space, whatever the
policy's action space: joint-position actions go through forward kinematics (FK); joint-velocity
actions are first integrated to joint positions from the current measured joint position, as the
authors' code does (``q_{k+1} = q_k + dt * qdot_k``, cumulative over the chunk).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import numpy as np

from fiper_ros.core.errors import CoreError


class KinematicsError(CoreError):
    """The kinematic model or the action layout is unusable."""


class ForwardKinematics(Protocol):
    """Maps joint configurations ``[N, joints]`` to EE positions ``[N, 3]``."""

    @property
    def joints(self) -> int:
        """Joint values per configuration (the action channels a joint-space projection takes)."""
        ...

    def __call__(self, q: np.ndarray) -> np.ndarray: ...


_AXES = {"X": np.array([1.0, 0.0, 0.0]), "Y": np.array([0.0, 1.0, 0.0]), "Z": np.array([0.0, 0.0, 1.0])}


@dataclass(frozen=True)
class _ChainJoint:
    """One joint on the path from the root to the EE frame.

    ``basis`` holds the fixed placement rotation ``Rp``, ``Rp K`` and ``Rp K^2`` (``K`` the
    cross-product matrix of the unit axis), so that for a revolute joint
    ``R Rp Rot(q) = R Rp + sin q (R Rp K) + (1 - cos q) (R Rp K^2)`` (Rodrigues) needs only matrix
    products with constants for all configurations at once.
    """

    translation: np.ndarray
    basis: tuple[np.ndarray, np.ndarray, np.ndarray]
    revolute: bool
    axis: np.ndarray
    q_index: int


def _cross_matrix(axis: np.ndarray) -> np.ndarray:
    x, y, z = axis
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


class PinocchioFK:
    """FK of one frame of a URDF model, read with pinocchio and evaluated batched in numpy.

    Pinocchio's Python API evaluates one configuration per call (about 2.5 us for the Panda hand, so
    13 ms for a 256 x 16 action batch). This class takes the joint placements, types and axes of the
    chain from the root to the frame out of the pinocchio model once and composes them for all
    configurations at once with numpy (``oMj = oMparent * placement_j * motion_j(q_j)``), which
    agrees with pinocchio to rounding (tested). URDF models have revolute and prismatic joints
    (aligned or not) on that chain; continuous and planar joints (``nq != nv``) are refused.

    A configuration holds either the values of the chain's joints, root first (:attr:`joints`
    columns: a Panda's seven arm joints, as a joint-space policy commands them), or the model's
    whole ``q`` (``model.nq`` columns, e.g. with the two finger joints).
    """

    def __init__(self, urdf_path: str | Path, frame: str) -> None:
        import pinocchio  # noqa: PLC0415 - optional dependency, only needed for joint-space actions

        path = Path(urdf_path)
        if not path.is_file():
            raise KinematicsError(f"URDF not found: {path}")
        self.model = pinocchio.buildModelFromUrdf(str(path))
        if self.model.nq != self.model.nv:
            raise KinematicsError(f"{path}: joints with nq != nv (continuous/planar/free) are not supported")
        if not self.model.existFrame(frame):
            raise KinematicsError(f"{path}: no frame named {frame!r}")
        self.frame = frame
        placement = self.model.frames[self.model.getFrameId(frame)]
        self._frame_offset = np.array(placement.placement.translation, dtype=np.float64)
        self._chain = self._read_chain(placement.parentJoint, path)

    def _read_chain(self, joint_id: int, path: Path) -> list[_ChainJoint]:
        chain: list[_ChainJoint] = []
        while joint_id > 0:
            joint = self.model.joints[joint_id]
            kind = joint.shortname().removeprefix("JointModel")
            if kind in ("RX", "RY", "RZ", "PX", "PY", "PZ"):
                axis = _AXES[kind[1]]
            elif kind in ("RevoluteUnaligned", "PrismaticUnaligned"):
                axis = np.array(joint.extract().axis, dtype=np.float64)
            else:
                raise KinematicsError(f"{path}: joint type {kind} on the chain to {self.frame!r} is not supported")
            placement = self.model.jointPlacements[joint_id]
            rotation = np.array(placement.rotation, dtype=np.float64)
            cross = _cross_matrix(axis)
            chain.append(
                _ChainJoint(
                    translation=np.array(placement.translation, dtype=np.float64),
                    basis=(rotation, rotation @ cross, rotation @ cross @ cross),
                    revolute=kind.startswith("R"),
                    axis=axis,
                    q_index=int(joint.idx_q),
                )
            )
            joint_id = self.model.parents[joint_id]
        return chain[::-1]

    @property
    def joints(self) -> int:
        """Number of joints on the chain from the root to the frame."""
        return len(self._chain)

    def __call__(self, q: np.ndarray) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        if q.ndim != 2 or q.shape[1] not in (self.joints, self.model.nq):
            raise KinematicsError(f"expected joint configurations [N, {self.joints}] (the chain to {self.frame!r}) "
                                  f"or [N, {self.model.nq}] (the whole model), got shape {q.shape}")
        columns = range(self.joints) if q.shape[1] == self.joints else [j.q_index for j in self._chain]
        n = q.shape[0]
        # Each sample's rotation is kept as 3 rows of a [N*3, 3] array: a product with a constant
        # matrix is one GEMM, and [N*3, 3] viewed as [N, 9] scales each sample by its own factor.
        rotation = np.tile(np.eye(3), (n, 1))
        position = np.zeros((n, 3))
        for joint, column in zip(self._chain, columns):
            position += (rotation @ joint.translation).reshape(n, 3)
            placed, placed_k, placed_kk = joint.basis
            values = q[:, column]
            rotated = rotation @ placed
            if joint.revolute:
                flat = rotated.reshape(n, 9)
                flat += np.sin(values)[:, None] * (rotation @ placed_k).reshape(n, 9)
                flat += (1.0 - np.cos(values))[:, None] * (rotation @ placed_kk).reshape(n, 9)
            else:
                position += (rotated @ joint.axis).reshape(n, 3) * values[:, None]
            rotation = rotated
        return position + (rotation @ self._frame_offset).reshape(n, 3)


def integrate_velocities(qdot: np.ndarray, q0: np.ndarray, dt: float) -> np.ndarray:
    """Joint positions ``[..., H, nq]`` after each velocity action ``qdot[..., H, nq]``.

    ``q_{k+1} = q_k + dt * qdot_k`` starting from the current joint position ``q0 [nq]``; the
    position reached after applying action ``k`` is returned at index ``k``.
    """
    if dt <= 0:
        raise KinematicsError(f"dt must be > 0, got {dt}")
    qdot = np.asarray(qdot, dtype=np.float64)
    q0 = np.asarray(q0, dtype=np.float64)
    if q0.shape != qdot.shape[-1:]:
        raise KinematicsError(f"q0 must have shape ({qdot.shape[-1]},), got {q0.shape}")
    return q0 + dt * np.cumsum(qdot, axis=-2)


@dataclass(frozen=True)
class ActionProjection:
    """Turns an action batch ``[B, H, D]`` into the positions ACE bins (App. A.1).

    Attributes:
        action_space: ``"ee_position"``, ``"joint_position"`` or ``"joint_velocity"``.
        dims: ``(start, stop)`` of the action channels used: the EE position channels for
            ``"ee_position"``, the joint channels for joint-space actions (a gripper channel after
            the joints is thus ignored). Default: the first three channels / the first
            ``fk.joints`` channels.
        fk: Forward kinematics, required for joint-space actions.
        dt: Seconds per action, required for ``"joint_velocity"``.
    """

    action_space: str = "ee_position"
    dims: tuple[int, int] | None = None
    fk: ForwardKinematics | None = None
    dt: float | None = None

    def __post_init__(self) -> None:
        if self.action_space != "ee_position" and self.fk is None:
            raise KinematicsError(f"action_space {self.action_space!r} needs forward kinematics (fk)")
        if self.action_space == "joint_velocity" and (self.dt is None or self.dt <= 0):
            raise KinematicsError("action_space 'joint_velocity' needs dt > 0")

    def _channels(self, actions: np.ndarray) -> np.ndarray:
        if self.dims is not None:
            start, stop = self.dims
        else:
            start, stop = 0, 3 if self.fk is None or self.action_space == "ee_position" else self.fk.joints
        picked = actions[..., start:stop]
        if picked.shape[-1] == 0:
            raise KinematicsError(f"channel range {self.dims} selects nothing from {actions.shape[-1]} channels")
        return picked

    def __call__(self, actions: np.ndarray, q_current: np.ndarray | None = None) -> np.ndarray:
        """Positions ``[B, H, P]`` (``P = 3`` for joint-space actions) of a batch ``[B, H, D]``.

        Args:
            actions: Sampled action chunks.
            q_current: Measured joint position ``[nq]``, required for ``"joint_velocity"``.
        """
        actions = np.asarray(actions, dtype=np.float64)
        if actions.ndim != 3:
            raise KinematicsError(f"actions must be [B, H, D], got shape {actions.shape}")
        channels = self._channels(actions)
        if self.action_space == "ee_position":
            return channels
        assert self.fk is not None
        if self.action_space == "joint_velocity":
            if q_current is None:
                raise KinematicsError("joint_velocity actions need the current joint position")
            channels = integrate_velocities(channels, q_current, float(self.dt))  # type: ignore[arg-type]
        batch, horizon, nq = channels.shape
        return np.asarray(self.fk(channels.reshape(batch * horizon, nq))).reshape(batch, horizon, 3)


@dataclass(frozen=True)
class RobotModel:
    """What maps a joint-space policy's actions to EE positions: a URDF, its EE frame, the period.

    Attributes:
        urdf: Path of the robot's URDF.
        ee_frame: The URDF frame whose position ACE bins.
        control_dt: Seconds per action, required for ``"joint_velocity"`` actions.
    """

    urdf: str
    ee_frame: str = "panda_hand"
    control_dt: float | None = None

    def forward_kinematics(self) -> PinocchioFK:
        """The batched FK of :attr:`ee_frame` (raises :class:`KinematicsError` on a bad URDF or frame)."""
        return PinocchioFK(self.urdf, self.ee_frame)

    def to_dict(self) -> dict[str, str | float | None]:
        """Plain data: the URDF by its content hash, so that a moved file keeps its meaning."""
        digest = hashlib.sha256(Path(self.urdf).read_bytes()).hexdigest() if Path(self.urdf).is_file() else None
        return {"urdf_sha256": digest, "ee_frame": self.ee_frame, "control_dt": self.control_dt}
