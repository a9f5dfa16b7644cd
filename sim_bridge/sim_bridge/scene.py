"""Scene construction with ``mujoco.MjSpec``: Panda, table, floor, lights, cameras and object helpers.

Everything that a scenario may change at the scene level (lighting, third-person camera pose, friction)
enters through ``SceneParams``. The table top is the plane z = 0 and the robot base sits at the origin.
"""
from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from .robot import panda_spec
from .transforms import camera_quat, yaw_quat

THIRD_CAMERA = "third"
TABLE_X = (-0.3, 0.85)
TABLE_Y = (-0.5, 0.5)
TABLE_THICKNESS = 0.04
FLOOR_Z = -0.75
TIMESTEP = 0.002
_THIRD_POS = np.array([1.05, 0.25, 0.7])
_THIRD_LOOKAT = np.array([0.45, 0.0, 0.05])


@dataclass(frozen=True)
class SceneParams:
    """Scene-level physical and visual parameters of one episode.

    Attributes:
        friction: Sliding friction coefficient of the table and of every object.
        light_scale: Multiplier of the main light's diffuse and ambient intensity.
        light_azimuth: Azimuth of the main light's direction [rad] (0: light from the front).
        camera_offset: Offset (3,) of the third-person camera position [m]; it keeps looking at the workspace.
    """

    friction: float = 0.5
    light_scale: float = 1.0
    light_azimuth: float = 0.0
    camera_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


def build_scene(params: SceneParams) -> mujoco.MjSpec:
    """Return a spec with the Panda, table, floor, light and both cameras (96x96 RGB, shadows off)."""
    spec = panda_spec()
    spec.option.timestep = TIMESTEP
    spec.visual.quality.shadowsize = 0
    spec.visual.headlight.ambient = (0.25, 0.25, 0.25)
    spec.visual.headlight.diffuse = (0.25, 0.25, 0.25)
    spec.visual.headlight.specular = (0.0, 0.0, 0.0)
    world = spec.worldbody
    half_x = (TABLE_X[1] - TABLE_X[0]) / 2.0
    half_y = (TABLE_Y[1] - TABLE_Y[0]) / 2.0
    world.add_geom(
        name="table",
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=(half_x, half_y, TABLE_THICKNESS / 2.0),
        pos=((TABLE_X[0] + TABLE_X[1]) / 2.0, (TABLE_Y[0] + TABLE_Y[1]) / 2.0, -TABLE_THICKNESS / 2.0),
        rgba=(0.62, 0.48, 0.34, 1.0),
        friction=(params.friction, 0.005, 0.0001),
    )
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=(3.0, 3.0, 0.1),
        pos=(0.0, 0.0, FLOOR_Z),
        rgba=(0.35, 0.37, 0.4, 1.0),
    )
    intensity = 0.7 * params.light_scale
    direction = np.array([-np.cos(params.light_azimuth), -np.sin(params.light_azimuth), -2.0])
    world.add_light(
        name="main",
        pos=tuple(-1.5 * direction),
        dir=tuple(direction / np.linalg.norm(direction)),
        diffuse=(intensity, intensity, intensity),
        ambient=(0.3 * params.light_scale,) * 3,
        specular=(0.1, 0.1, 0.1),
        castshadow=False,
        type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL,
    )
    cam_pos = _THIRD_POS + np.asarray(params.camera_offset)
    world.add_camera(
        name=THIRD_CAMERA,
        pos=tuple(cam_pos),
        quat=tuple(camera_quat(_THIRD_LOOKAT - cam_pos, np.array([0.0, 0.0, 1.0]))),
        fovy=50.0,
    )
    return spec


def add_box_body(
    spec: mujoco.MjSpec,
    name: str,
    half_size: tuple[float, float, float],
    pos: tuple[float, float, float],
    yaw: float,
    rgba: tuple[float, float, float, float],
    mass: float,
    friction: float,
) -> mujoco.MjsBody:
    """Add a free-floating box body named ``name`` (geom ``name``) and return it.

    The geom has contact priority 1, so its ``friction`` (not the larger one of the fingers) applies
    in every contact it makes.
    """
    body = spec.worldbody.add_body(name=name, pos=pos, quat=tuple(yaw_quat(yaw)))
    body.add_freejoint(name=name)
    body.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=half_size,
        rgba=rgba,
        mass=mass,
        friction=(friction, 0.005, 0.0001),
        priority=1,
    )
    return body


def add_patch(
    spec: mujoco.MjSpec,
    name: str,
    center: tuple[float, float],
    half_size: tuple[float, float],
    rgba: tuple[float, float, float, float],
) -> None:
    """Add a flat coloured, non-colliding region marker lying on the table top."""
    spec.worldbody.add_geom(
        name=name,
        type=mujoco.mjtGeom.mjGEOM_BOX,
        size=(half_size[0], half_size[1], 0.001),
        pos=(center[0], center[1], 0.001),
        rgba=rgba,
        contype=0,
        conaffinity=0,
    )
