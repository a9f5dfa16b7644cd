"""Joint-space actions to EE positions (App. A.1) with a 2-link planar arm written here."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_ros.core.kinematics import ActionProjection, KinematicsError, PinocchioFK, integrate_velocities
from helpers.urdfs import L1, L2, PLANAR_URDF, SPATIAL_URDF
from sim_bridge.robot import URDF_PATH

def analytic(q: np.ndarray) -> np.ndarray:
    q1, q2 = q[..., 0], q[..., 1]
    x = L1 * np.cos(q1) + L2 * np.cos(q1 + q2)
    y = L1 * np.sin(q1) + L2 * np.sin(q1 + q2)
    return np.stack([x, y, np.zeros_like(x)], axis=-1)


@pytest.fixture(scope="module")
def fk(tmp_path_factory: pytest.TempPathFactory) -> PinocchioFK:
    path = tmp_path_factory.mktemp("urdf") / "planar2.urdf"
    path.write_text(PLANAR_URDF)
    return PinocchioFK(path, "tip")


def test_fk_matches_the_analytic_formula(fk: PinocchioFK) -> None:
    q = np.random.default_rng(0).uniform(-3, 3, size=(50, 2))
    assert np.allclose(fk(q), analytic(q), atol=1e-12)


def test_batched_fk_matches_pinocchio_on_a_spatial_chain(tmp_path: Path) -> None:
    import pinocchio

    path = tmp_path / "spatial3.urdf"
    path.write_text(SPATIAL_URDF)
    fk = PinocchioFK(path, "ee")
    model = pinocchio.buildModelFromUrdf(str(path))
    data, frame = model.createData(), model.getFrameId("ee")
    q = np.random.default_rng(2).uniform(-1, 1, size=(40, 3))
    expected = []
    for config in q:
        pinocchio.forwardKinematics(model, data, config)
        expected.append(pinocchio.updateFramePlacement(model, data, frame).translation.copy())
    assert np.allclose(fk(q), expected, atol=1e-12)


def test_joint_position_actions_ignore_the_gripper_channel(fk: PinocchioFK) -> None:
    rng = np.random.default_rng(1)
    actions = rng.uniform(-2, 2, size=(6, 5, 3))  # 2 joints + gripper
    projection = ActionProjection("joint_position", dims=(0, 2), fk=fk)
    assert np.allclose(projection(actions), analytic(actions[..., :2]), atol=1e-12)


def test_velocity_actions_are_integrated_from_the_current_position(fk: PinocchioFK) -> None:
    qdot = np.array([[[1.0, 0.0], [1.0, -2.0], [0.0, 2.0]]])  # [B=1, H=3, nq=2]
    q0 = np.array([0.1, 0.2])
    q = integrate_velocities(qdot, q0, 0.5)
    assert np.allclose(q[0], [[0.6, 0.2], [1.1, -0.8], [1.1, 0.2]])
    projection = ActionProjection("joint_velocity", fk=fk, dt=0.5)
    assert np.allclose(projection(qdot, q0), analytic(q), atol=1e-12)
    with pytest.raises(KinematicsError, match="current joint position"):
        projection(qdot)


def test_ee_positions_take_the_first_three_channels() -> None:
    actions = np.arange(2 * 3 * 7, dtype=float).reshape(2, 3, 7)
    assert np.array_equal(ActionProjection()(actions), actions[..., :3])


def test_configuration_errors(tmp_path: Path, fk: PinocchioFK) -> None:
    with pytest.raises(KinematicsError, match="needs forward kinematics"):
        ActionProjection("joint_position")
    with pytest.raises(KinematicsError, match="dt"):
        ActionProjection("joint_velocity", fk=fk)
    with pytest.raises(KinematicsError, match="URDF not found"):
        PinocchioFK(tmp_path / "missing.urdf", "tip")
    with pytest.raises(KinematicsError, match="no frame"):
        PinocchioFK(fk_path(tmp_path), "hand")
    with pytest.raises(KinematicsError, match=r"\[N, 2\]"):
        fk(np.zeros((3, 7)))


def fk_path(directory: Path) -> Path:
    path = directory / "planar2.urdf"
    path.write_text(PLANAR_URDF)
    return path


def test_panda_takes_its_seven_arm_joints_or_the_whole_model_and_agrees_with_pinocchio() -> None:
    import pinocchio

    fk = PinocchioFK(URDF_PATH, "panda_hand_tcp")
    assert (fk.joints, fk.model.nq) == (7, 9)  # two finger joints are off the chain to the TCP
    rng = np.random.default_rng(3)
    arm = rng.uniform(-1.5, 1.5, size=(20, 7))
    whole = np.concatenate([arm, rng.uniform(0.0, 0.04, size=(20, 2))], axis=1)
    data = fk.model.createData()
    frame = fk.model.getFrameId("panda_hand_tcp")
    expected = []
    for config in whole:
        pinocchio.forwardKinematics(fk.model, data, config)
        expected.append(pinocchio.updateFramePlacement(fk.model, data, frame).translation.copy())
    assert np.allclose(fk(arm), expected, atol=1e-12)
    assert np.allclose(fk(whole), expected, atol=1e-12)
    with pytest.raises(KinematicsError, match=r"\[N, 7\].*\[N, 9\]"):
        fk(whole[:, :8])


def test_panda_velocity_actions_default_to_the_arm_channels_and_ignore_the_gripper() -> None:
    fk = PinocchioFK(URDF_PATH, "panda_hand")
    rng = np.random.default_rng(4)
    actions = rng.uniform(-0.3, 0.3, size=(4, 8, 8))  # B = 4, H = 8: 7 joint velocities + gripper opening
    q0 = np.array([0.0, -0.5, 0.0, -2.2, 0.0, 1.7, 0.8])
    positions = ActionProjection("joint_velocity", fk=fk, dt=0.1)(actions, q0)
    assert positions.shape == (4, 8, 3)
    moved = actions.copy()
    moved[..., 7] += 1.0
    assert np.array_equal(ActionProjection("joint_velocity", fk=fk, dt=0.1)(moved, q0), positions)
    assert np.allclose(positions[:, 0], fk(q0 + 0.1 * actions[:, 0, :7]), atol=1e-12)
