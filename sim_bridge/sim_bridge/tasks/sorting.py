"""Sorting: push a red and a blue block into the colour-matching box regions on the table.

Actions are planar TCP targets (D = 2). Success: both block centres lie inside their boxes. A block
falling off the table ends the episode as a failure. H = 8, h = 4, 75 policy steps at 10 Hz.
"""
from __future__ import annotations

from typing import Any

import mujoco
import numpy as np

from ..scene import add_box_body, add_patch
from ..transforms import quat_yaw, yaw_quat
from .base import OFF_TABLE_Z
from .planar import PlanarPushEnv

COLORS: tuple[str, str] = ("red", "blue")
BLOCK_HALF = 0.025
BLOCK_MASS = 0.08
BOX_HALF = 0.065
BOX_X = 0.64
BOX_Y = 0.27
"""ID box centres: (BOX_X, +BOX_Y) red, (BOX_X, -BOX_Y) blue, each jittered by up to BOX_JITTER."""
BOX_JITTER = 0.02
BLOCK_X = (0.38, 0.50)
BLOCK_Y = (-0.15, 0.15)
_RGBA = {"red": (0.85, 0.12, 0.12, 1.0), "blue": (0.12, 0.28, 0.85, 1.0)}
_BOX_RGBA = {"red": (0.95, 0.6, 0.6, 1.0), "blue": (0.6, 0.7, 0.98, 1.0)}


def _segment_distance(point: np.ndarray, start: np.ndarray, end: np.ndarray) -> float:
    """Distance from ``point`` to the segment ``start``-``end``."""
    seg = end - start
    t = np.clip(np.dot(point - start, seg) / np.dot(seg, seg), 0.0, 1.0)
    return float(np.linalg.norm(point - (start + t * seg)))


class SortingEnv(PlanarPushEnv):
    """Sorting task (see module docstring)."""

    name = "sorting"
    horizon = 8
    exec_steps = 4
    max_policy_steps = 75

    def _sample_layout(self, rng: np.random.Generator) -> None:
        # The knob scales the footprint only: taller blocks would hit the hand housing above the pads.
        self.block_half = BLOCK_HALF * self.knobs["block_scale"]
        sign = {"red": 1.0, "blue": -1.0}
        box_x = BOX_X - self.knobs["box_shift"]
        self.boxes = {
            c: np.array([box_x, sign[c] * BOX_Y]) + rng.uniform(-BOX_JITTER, BOX_JITTER, 2) for c in COLORS
        }
        clearance = 2.0 * np.sqrt(2.0) * self.block_half + 0.03
        while True:
            blocks = {c: np.array([rng.uniform(*BLOCK_X), rng.uniform(*BLOCK_Y)]) for c in COLORS}
            red, blue = blocks["red"], blocks["blue"]
            if (
                _segment_distance(blue, red, self.boxes["red"]) > clearance
                and _segment_distance(red, blue, self.boxes["blue"]) > clearance
            ):
                break
        self.block_start = blocks
        self.block_yaw = {c: float(rng.uniform(-np.pi / 4, np.pi / 4)) for c in COLORS}
        self.start_xy = np.array([0.30, rng.uniform(-0.05, 0.05)])

    def _add_objects(self, spec: mujoco.MjSpec) -> None:
        mass = BLOCK_MASS * self.knobs["mass_scale"] * self.knobs["block_scale"] ** 2
        for c in COLORS:
            add_patch(spec, f"box_{c}", tuple(self.boxes[c]), (BOX_HALF, BOX_HALF), _BOX_RGBA[c])
            add_box_body(
                spec, f"block_{c}", (self.block_half, self.block_half, BLOCK_HALF), (*self.block_start[c], BLOCK_HALF),
                self.block_yaw[c], _RGBA[c], mass, self.knobs["friction"],
            )

    def _start_xy(self) -> np.ndarray:
        return self.start_xy

    def _place_objects(self) -> None:
        for c in COLORS:
            self.set_free_pose(
                f"block_{c}", np.array([*self.block_start[c], BLOCK_HALF]), yaw_quat(self.block_yaw[c])
            )

    def in_box(self, color: str) -> bool:
        """Whether the ``color`` block's centre lies inside its box region (and on the table)."""
        pos, _ = self.free_pose(f"block_{color}")
        return bool(np.all(np.abs(pos[:2] - self.boxes[color]) <= BOX_HALF) and pos[2] > 0.0)

    def _evaluate(self) -> tuple[bool, bool]:
        off_table = any(self.free_pose(f"block_{c}")[0][2] < OFF_TABLE_Z for c in COLORS)
        return all(self.in_box(c) for c in COLORS) and not off_table, off_table

    def state(self) -> dict[str, Any]:
        blocks = {}
        for c in COLORS:
            pos, quat = self.free_pose(f"block_{c}")
            blocks[c] = {"pos": pos, "yaw": quat_yaw(quat), "in_box": self.in_box(c)}
        return {
            "tcp": self.tcp_pos(),
            "ee_cmd": self.ee_cmd.copy(),
            "blocks": blocks,
            "boxes": {c: b.copy() for c, b in self.boxes.items()},
            "block_half": self.block_half,  # half side in the plane; the height is always 2 * BLOCK_HALF
            "box_half": BOX_HALF,
        }
