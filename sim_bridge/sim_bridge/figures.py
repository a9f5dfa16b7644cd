"""Camera figures for docs/sim.md: ``sim_<task>_<camera>.png`` of each task's first ID observation."""
from __future__ import annotations

from pathlib import Path

from PIL import Image

from .env import make_env
from .render import CAMERAS
from .scenarios import TASK_NAMES

UPSCALE = 2


def write_camera_figures(out_dir: Path, seed: int = 0) -> list[Path]:
    """Write both 96x96 camera views of every task (ID, ``seed``), upscaled 2x (nearest), and return the paths."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    paths = []
    for task in TASK_NAMES:
        with make_env(task, "id", seed) as env:
            obs = env.reset()
        for key in CAMERAS:
            image = Image.fromarray(obs[key])
            path = out_dir / f"sim_{task}_{key.removesuffix('_rgb')}.png"
            image.resize((image.width * UPSCALE, image.height * UPSCALE), Image.NEAREST).save(path)
            paths.append(path)
    return paths
