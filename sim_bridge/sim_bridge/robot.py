"""Franka Panda model: the example-robot-data URDF turned into a MuJoCo spec with actuators.

The URDF is loaded unchanged from ``assets/panda``; its ``package://`` mesh paths are rewritten in
memory to the bundled STL collision meshes (also used for rendering). ``panda_spec`` adds what the
URDF lacks: gravity compensation, joint armature and damping, position servos for the seven arm
joints, a position servo per finger of the parallel gripper, a tool-centre-point site and a
wrist camera.
"""
from __future__ import annotations

import re
from pathlib import Path

import mujoco
import numpy as np

from fiper_ros.interface.topics import ARM_JOINT_NAMES

from .transforms import camera_quat

PANDA_DIR = Path(__file__).resolve().parent / "assets" / "panda"
URDF_PATH = PANDA_DIR / "urdf" / "panda.urdf"

ARM_JOINTS: tuple[str, ...] = ARM_JOINT_NAMES
FINGER_JOINTS: tuple[str, str] = ("panda_finger_joint1", "panda_finger_joint2")
HAND_BODY = "panda_hand"
TCP_SITE = "tcp"
WRIST_CAMERA = "wrist"
GRIPPER_ACTUATORS: tuple[str, str] = ("gripper_left", "gripper_right")
"""One position servo per finger, always given the same target (the URDF mimic joint stays as an equality)."""
TCP_OFFSET = 0.1034
"""Distance of the tool centre point (between the finger pads) from the hand frame, as in the URDF."""
FINGER_MAX = 0.04
"""Opening of one finger joint at full stroke [m]; the gripper width is twice the joint position."""

HOME_QPOS = np.array([0.0, -0.25, 0.0, -2.3, 0.0, 2.05, np.pi / 4])
"""Arm posture used as IK seed and null-space target: hand above the table, pointing down."""

# Position-servo stiffness per arm joint [Nm/rad] (values of the usual Panda MuJoCo models).
_ARM_KP = (4500.0, 4500.0, 3500.0, 3500.0, 2000.0, 2000.0, 2000.0)
_ARM_EFFORT = (87.0, 87.0, 87.0, 87.0, 12.0, 12.0, 12.0)
_GRIPPER_KP = 2500.0
_GRIPPER_FORCE = 70.0
_COLLIDING_BODIES = ("panda_hand", "panda_leftfinger", "panda_rightfinger")
_LINK_RGBA = (0.85, 0.86, 0.88, 1.0)
_FINGER_RGBA = (0.25, 0.25, 0.25, 1.0)
_MESH_PATTERN = re.compile(
    r"package://example-robot-data/robots/panda_description/meshes/(?:visual|collision)/(\w+)\.(?:dae|stl)"
)


def urdf_text() -> str:
    """Return the Panda URDF with every mesh path pointing at the bundled STL collision meshes."""
    mesh_dir = PANDA_DIR / "meshes" / "collision"
    text = URDF_PATH.read_text()
    return _MESH_PATTERN.sub(lambda m: str(mesh_dir / f"{m.group(1)}.stl"), text)


def panda_spec() -> mujoco.MjSpec:
    """Build a MuJoCo spec of the Panda (base at the world origin) with actuators, TCP site and wrist camera."""
    text = urdf_text().replace(
        "<robot name=\"panda\" xmlns:xacro=\"http://www.ros.org/wiki/xacro\">",
        "<robot name=\"panda\"><mujoco><compiler fusestatic=\"false\"/></mujoco>",
    )
    spec = mujoco.MjSpec.from_string(text)
    # URDF parsing already dropped the <visual> elements; keep the non-colliding geoms added from here on.
    spec.compiler.discardvisual = False
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # Elliptic cones with a high impedance ratio keep grasped objects from creeping out of the fingers.
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0
    for body in spec.worldbody.find_all(mujoco.mjtObj.mjOBJ_BODY):
        body.gravcomp = 1.0
        collides = body.name in _COLLIDING_BODIES
        for geom in body.geoms:
            geom.contype = geom.conaffinity = 1 if collides else 0
            geom.rgba = _FINGER_RGBA if "finger" in body.name else _LINK_RGBA
            geom.friction = (1.0, 0.005, 0.0001)
    spec.add_exclude(bodyname1="panda_leftfinger", bodyname2="panda_rightfinger")
    for name, kp, effort in zip(ARM_JOINTS, _ARM_KP, _ARM_EFFORT):
        joint = spec.joint(name)
        joint.armature = 0.1
        joint.damping = (1.0, 0.0, 0.0)
        act = spec.add_actuator(name=name, target=name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=kp, kv=0.1 * kp)
        act.ctrlrange = joint.range
        act.forcerange = (-effort, effort)
    for name in FINGER_JOINTS:
        # Heavy damping limits the closing speed to about 0.3 m/s: fast fingers tunnel through blocks.
        spec.joint(name).armature = 0.01
        spec.joint(name).damping = (200.0, 0.0, 0.0)
    for name, joint in zip(GRIPPER_ACTUATORS, FINGER_JOINTS):
        act = spec.add_actuator(name=name, target=joint, trntype=mujoco.mjtTrn.mjTRN_JOINT)
        act.set_to_position(kp=_GRIPPER_KP, kv=50.0)
        act.ctrlrange = (0.0, FINGER_MAX)
        act.forcerange = (-_GRIPPER_FORCE, _GRIPPER_FORCE)
    hand = spec.body(HAND_BODY)
    hand.add_site(name=TCP_SITE, pos=(0.0, 0.0, TCP_OFFSET), size=(0.005, 0.005, 0.005), group=4)
    # In the hand frame: below the hand's housing on its robot-facing side, looking forward (hand +x,
    # world +x when the hand points down at yaw 0) and down (hand +z) past the fingers.
    hand.add_camera(
        name=WRIST_CAMERA,
        pos=(-0.07, 0.0, 0.075),
        fovy=80.0,
        quat=camera_quat(np.array([1.2, 0.0, 1.0]), np.array([1.0, 0.0, 0.0])),
    )
    return spec
