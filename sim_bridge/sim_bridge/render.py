"""Offscreen rendering of the wrist and third-person cameras (96x96 RGB by default)."""
from __future__ import annotations

import mujoco
import numpy as np

from .robot import WRIST_CAMERA
from .scene import THIRD_CAMERA

IMAGE_SIZE = 96
CAMERAS: dict[str, str] = {"wrist_rgb": WRIST_CAMERA, "third_rgb": THIRD_CAMERA}
"""Observation key -> MuJoCo camera name."""


class CameraRenderer:
    """Renders every camera of ``CAMERAS`` into uint8 arrays of shape (size, size, 3)."""

    def __init__(self, model: mujoco.MjModel, size: int = IMAGE_SIZE) -> None:
        """Create an offscreen context for ``model`` (set ``MUJOCO_GL=egl`` on headless machines)."""
        self._renderer = mujoco.Renderer(model, height=size, width=size)

    def render(self, data: mujoco.MjData) -> dict[str, np.ndarray]:
        """Return ``{observation key: image}`` for the current state of ``data``."""
        images = {}
        for key, camera in CAMERAS.items():
            self._renderer.update_scene(data, camera=camera)
            images[key] = self._renderer.render().copy()
        return images

    def close(self) -> None:
        """Release the rendering context."""
        self._renderer.close()
