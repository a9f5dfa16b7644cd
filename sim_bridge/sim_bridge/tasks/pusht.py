"""PushT: push a T-shaped block into a goal pose with the closed gripper as the pusher.

Actions are planar TCP targets (D = 2). Success: at least 90% of the goal T's area is covered by the
T (computed on a 2.5 mm raster of the goal shape). H = 16, h = 8, 38 policy steps at 10 Hz as in the
paper.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import mujoco
import numpy as np

from ..planar import Rect
from ..transforms import quat_yaw, yaw_quat
from .base import OFF_TABLE_Z
from .planar import PlanarPushEnv

BAR = (0.20, 0.05)
"""ID bar length and width [m]."""
STEM = (0.05, 0.15)
"""ID stem width and length [m]."""
T_HEIGHT = 0.03
T_MASS = 0.2
GOAL_POSE = (0.5, 0.0, np.pi / 4)
SUCCESS_COVERAGE = 0.9
RASTER = 0.0025
T_X = (0.42, 0.56)
T_Y = (-0.16, 0.16)
_T_RGBA = (0.35, 0.45, 0.55, 1.0)
_GOAL_RGBA = (0.45, 0.8, 0.45, 1.0)


@dataclass(frozen=True)
class TShape:
    """A T made of a bar (x-extent ``bar_len``, width ``bar_w``) on top of a stem, in its COM frame.

    The bar is parallel to the frame's x axis, the stem points along -y.
    """

    bar_len: float
    bar_w: float
    stem_w: float
    stem_len: float

    @property
    def com_y(self) -> float:
        """Height of the centre of mass above the stem's lower end."""
        bar_area, stem_area = self.bar_len * self.bar_w, self.stem_w * self.stem_len
        return (bar_area * (self.stem_len + self.bar_w / 2) + stem_area * self.stem_len / 2) / (bar_area + stem_area)

    def parts(self) -> list[tuple[np.ndarray, np.ndarray]]:
        """(centre, half extents) of the bar and the stem in the COM frame."""
        bar_c = np.array([0.0, self.stem_len + self.bar_w / 2 - self.com_y])
        stem_c = np.array([0.0, self.stem_len / 2 - self.com_y])
        return [(bar_c, np.array([self.bar_len, self.bar_w]) / 2), (stem_c, np.array([self.stem_w, self.stem_len]) / 2)]

    def rects(self, pose: np.ndarray) -> list[Rect]:
        """World rectangles of the T at ``pose`` = (x, y, yaw)."""
        frame = Rect(np.asarray(pose[:2], dtype=float), np.zeros(2), float(pose[2]))
        return [Rect(frame.to_world(c), h, float(pose[2])) for c, h in self.parts()]

    def contains_local(self, points: np.ndarray) -> np.ndarray:
        """Whether COM-frame points (..., 2) lie inside the T."""
        inside = np.zeros(points.shape[:-1], dtype=bool)
        for center, half in self.parts():
            inside |= np.all(np.abs(points - center) <= half, axis=-1)
        return inside

    def raster(self, spacing: float = RASTER) -> np.ndarray:
        """Cell centres (N, 2) of a square grid covering the T, in the COM frame."""
        extent = max(self.bar_len, self.stem_len + self.bar_w) + spacing
        axis = np.arange(-extent, extent, spacing) + spacing / 2
        grid = np.stack(np.meshgrid(axis, axis), axis=-1).reshape(-1, 2)
        return grid[self.contains_local(grid)]


def coverage_many(shape: TShape, poses: np.ndarray, goal_points: np.ndarray) -> np.ndarray:
    """Fractions (K,) of the goal raster points (N, 2), world frame, covered by the T at each of ``poses`` (K, 3)."""
    poses = np.atleast_2d(poses)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    rel = goal_points[None] - poses[:, None, :2]
    local = np.stack([c * rel[..., 0] + s * rel[..., 1], -s * rel[..., 0] + c * rel[..., 1]], axis=-1)
    return shape.contains_local(local).mean(axis=1)


def coverage(shape: TShape, pose: np.ndarray, goal_points: np.ndarray) -> float:
    """Fraction of the goal raster points (world frame) covered by the T at ``pose`` (x, y, yaw)."""
    return float(coverage_many(shape, pose, goal_points)[0])


class PushTEnv(PlanarPushEnv):
    """PushT task (see module docstring)."""

    name = "pusht"
    horizon = 16
    exec_steps = 8
    max_policy_steps = 38

    def _sample_layout(self, rng: np.random.Generator) -> None:
        k = self.knobs
        self.shape = TShape(
            bar_len=BAR[0] * k["t_scale"] * k["bar_scale"],
            bar_w=BAR[1] * k["t_scale"],
            stem_w=STEM[0] * k["t_scale"],
            stem_len=STEM[1] * k["t_scale"] * k["stem_scale"],
        )
        goal_shape = TShape(BAR[0], BAR[1], STEM[0], STEM[1])
        self.goal = np.array(GOAL_POSE)
        self._goal_rects = goal_shape.rects(self.goal)
        goal_frame = Rect(self.goal[:2], np.zeros(2), float(self.goal[2]))
        self.goal_points = goal_frame.to_world(goal_shape.raster())
        while True:
            pose = np.array([rng.uniform(*T_X), rng.uniform(*T_Y), rng.uniform(-np.pi, np.pi)])
            if coverage(self.shape, pose, self.goal_points) < 0.6:
                break
        self.t_start = pose
        while True:
            start = np.array([rng.uniform(0.28, 0.36), rng.uniform(-0.3, 0.3)])
            if not any(r.contains(start, 0.04) for r in self.shape.rects(pose)):
                break
        self.start_xy = start

    def _add_objects(self, spec: mujoco.MjSpec) -> None:
        for i, rect in enumerate(self._goal_rects):
            spec.worldbody.add_geom(
                name=f"goal_{i}", type=mujoco.mjtGeom.mjGEOM_BOX, size=(*rect.half, 0.001),
                pos=(*rect.center, 0.001), quat=tuple(yaw_quat(rect.yaw)), rgba=_GOAL_RGBA,
                contype=0, conaffinity=0,
            )
        body = spec.worldbody.add_body(name="tblock", pos=(*self.t_start[:2], T_HEIGHT / 2))
        body.add_freejoint(name="tblock")
        parts = self.shape.parts()
        mass = T_MASS * self.knobs["mass_scale"] * self.knobs["t_scale"] ** 2
        areas = [4 * h[0] * h[1] for _, h in parts]
        for i, ((center, half), area) in enumerate(zip(parts, areas)):
            body.add_geom(
                name=f"tblock_{i}", type=mujoco.mjtGeom.mjGEOM_BOX, size=(*half, T_HEIGHT / 2),
                pos=(*center, 0.0), rgba=_T_RGBA, mass=mass * area / sum(areas),
                friction=(self.knobs["friction"], 0.005, 0.0001), priority=1,
            )

    def _start_xy(self) -> np.ndarray:
        return self.start_xy

    def _place_objects(self) -> None:
        self.set_free_pose("tblock", np.array([*self.t_start[:2], T_HEIGHT / 2]), yaw_quat(self.t_start[2]))

    def t_pose(self) -> np.ndarray:
        """Current planar pose (x, y, yaw) of the T's centre of mass frame."""
        pos, quat = self.free_pose("tblock")
        return np.array([pos[0], pos[1], quat_yaw(quat)])

    def coverage(self) -> float:
        """Fraction of the goal T covered by the T."""
        return coverage(self.shape, self.t_pose(), self.goal_points)

    def _evaluate(self) -> tuple[bool, bool]:
        off_table = bool(self.free_pose("tblock")[0][2] < OFF_TABLE_Z)
        return self.coverage() >= SUCCESS_COVERAGE and not off_table, off_table

    def state(self) -> dict[str, Any]:
        return {
            "tcp": self.tcp_pos(),
            "ee_cmd": self.ee_cmd.copy(),
            "t_pose": self.t_pose(),
            "goal": self.goal.copy(),
            "shape": self.shape,
            "goal_points": self.goal_points,
            "coverage": self.coverage(),
        }
