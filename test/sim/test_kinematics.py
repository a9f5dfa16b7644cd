"""MuJoCo's Panda hand pose equals pinocchio's for the same URDF; the IK layer reaches its targets."""
from __future__ import annotations

import mujoco
import numpy as np
import pinocchio

from sim_bridge.ik import DiffIK
from sim_bridge.robot import ARM_JOINTS, HAND_BODY, HOME_QPOS, panda_spec, urdf_text
from sim_bridge.transforms import hand_down_quat


def test_hand_pose_matches_pinocchio() -> None:
    model = panda_spec().compile()
    data = mujoco.MjData(model)
    pin_model = pinocchio.buildModelFromXML(urdf_text())
    pin_data = pin_model.createData()
    frame = pin_model.getFrameId(HAND_BODY)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = np.array([rng.uniform(*model.joint(j).range) for j in ARM_JOINTS])
        data.qpos[:] = 0.0
        for name, value in zip(ARM_JOINTS, q):
            data.qpos[model.joint(name).qposadr[0]] = value
        mujoco.mj_kinematics(model, data)
        q_pin = pinocchio.neutral(pin_model)
        for name, value in zip(ARM_JOINTS, q):
            q_pin[pin_model.joints[pin_model.getJointId(name)].idx_q] = value
        pinocchio.framesForwardKinematics(pin_model, pin_data, q_pin)
        placement = pin_data.oMf[frame]
        body = model.body(HAND_BODY).id
        np.testing.assert_allclose(data.xpos[body], placement.translation, atol=1e-6)
        np.testing.assert_allclose(data.xmat[body].reshape(3, 3), placement.rotation, atol=1e-6)


def test_ik_reaches_target() -> None:
    model = panda_spec().compile()
    ik = DiffIK(model)
    target, quat = np.array([0.5, 0.1, 0.05]), hand_down_quat(0.3)
    q = ik.solve(HOME_QPOS, target, quat, iterations=100)
    pos, reached = ik.forward(q)
    np.testing.assert_allclose(pos, target, atol=1e-3)
    assert abs(abs(np.dot(reached, quat)) - 1.0) < 1e-5
