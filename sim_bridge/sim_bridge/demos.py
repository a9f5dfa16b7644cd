"""Demonstration datasets: one compressed ``.npz`` per expert episode, resumable.

File ``<out>/episode_<seed:06d>.npz`` holds (T = number of control steps of the episode):

- ``wrist_rgb``, ``third_rgb``: uint8 (T, 96, 96, 3), the observation before each action;
- ``proprio``: float32 (T, P); ``actions``: float32 (T, D), the expert's action at each step;
- ``success``, ``failed``: bool scalars; ``seed``: int; ``task``, ``scenario``: str;
- ``control_hz``: float; ``horizon``, ``exec_steps``: int (the task's H and h).

Files are written to a temporary name and renamed, so an interrupted run leaves no partial episode
and a rerun skips every finished one.
"""
from __future__ import annotations

import logging
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .env import make_env
from .experts import make_expert

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class EpisodeSummary:
    """Outcome of one recorded (or skipped) episode."""

    seed: int
    path: Path
    success: bool
    steps: int
    seconds: float
    skipped: bool


def episode_path(out_dir: Path, seed: int) -> Path:
    """File name of the episode with ``seed``."""
    return Path(out_dir) / f"episode_{seed:06d}.npz"


def record_episode(task: str, scenario: str, seed: int, path: Path) -> EpisodeSummary:
    """Run the expert on one episode with images and write it to ``path``."""
    start = time.perf_counter()
    columns: dict[str, list[np.ndarray]] = {"wrist_rgb": [], "third_rgb": [], "proprio": [], "actions": []}
    with make_env(task, scenario, seed) as env:
        obs = env.reset()
        expert = make_expert(env)
        while not env.done:
            action = expert.act(env.state())
            for key in ("wrist_rgb", "third_rgb", "proprio"):
                columns[key].append(obs[key])
            columns["actions"].append(np.asarray(action, dtype=np.float32))
            obs, _, info = env.step(action)
        arrays = {key: np.stack(value) for key, value in columns.items()}
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez_compressed(
            tmp, **arrays, success=info["success"], failed=info["failed"], seed=seed, task=task,
            scenario=scenario, control_hz=env.control_hz, horizon=env.horizon, exec_steps=env.exec_steps,
        )
    os.replace(tmp, path)
    return EpisodeSummary(seed, path, bool(info["success"]), len(arrays["actions"]),
                          time.perf_counter() - start, skipped=False)


def record_dataset(
    task: str,
    out_dir: Path,
    episodes: int,
    first_seed: int = 0,
    scenario: str = "id",
    progress: Callable[[int, EpisodeSummary], None] | None = None,
) -> list[EpisodeSummary]:
    """Record ``episodes`` expert episodes with seeds ``first_seed ...``, skipping existing files.

    Args:
        progress: Called after each episode with its index and summary.
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    summaries = []
    for index, seed in enumerate(range(first_seed, first_seed + episodes)):
        path = episode_path(out_dir, seed)
        if path.exists():
            with np.load(path) as data:
                summary = EpisodeSummary(seed, path, bool(data["success"]), len(data["actions"]), 0.0, True)
        else:
            summary = record_episode(task, scenario, seed, path)
            LOG.debug("recorded %s", path)
        summaries.append(summary)
        if progress is not None:
            progress(index, summary)
    return summaries
