"""Action multimodality at the initial state: the B sampled chunks' TCP paths over the scene's top view.

For planar tasks (``ee_position`` actions) a chunk *is* a TCP path in the table plane. ``block_choice``
tells which Sorting block each sampled path heads for (the demonstrations' mode: either block first).
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from fiper_ros.policy.noise import sampling_generator
from fiper_ros.policy.policy import Policy

from .env import make_env

if TYPE_CHECKING:
    from matplotlib.axes import Axes

SORTING_COLORS = {"red": "tab:red", "blue": "tab:blue"}


def initial_batch(policy: Policy, seed: int, batch: int | None = None,
                  scenario: str = "id") -> tuple[dict, np.ndarray]:
    """Privileged state and the ``[B, H, D]`` chunks sampled at the first observation of an episode."""
    with make_env(policy.config.task, scenario, seed) as env:
        obs = env.reset()
        state = env.state()
    _, chunks = policy.act([obs], batch, sampling_generator(seed))
    return state, chunks


def block_choice(state: dict, chunks: np.ndarray) -> np.ndarray:
    """Sorting: per chunk, the colour index (0 red, 1 blue) of the block its path ends closer to,
    measured along the direction from the TCP (cosine of the heading to each block)."""
    start = np.asarray(state["tcp"][:2])
    heading = chunks[:, -1, :2] - start
    scores = []
    for color in SORTING_COLORS:
        direction = np.asarray(state["blocks"][color]["pos"][:2]) - start
        scores.append(heading @ direction / (np.linalg.norm(heading, axis=1) * np.linalg.norm(direction) + 1e-9))
    return np.argmax(np.stack(scores, axis=1), axis=1)


def _square(ax: Axes, center: np.ndarray, half: float, yaw: float, **style: Any) -> None:
    from matplotlib.patches import Polygon  # noqa: PLC0415

    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]]) * half
    rotation = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    ax.add_patch(Polygon(center[:2] + corners @ rotation.T, closed=True, **style))


def _draw_scene(ax: Axes, task: str, state: dict) -> None:
    if task == "sorting":
        for color, mpl in SORTING_COLORS.items():
            _square(ax, np.asarray(state["boxes"][color]), state["box_half"], 0.0, fill=False, ec=mpl, lw=2, ls="--")
            block = state["blocks"][color]
            _square(ax, np.asarray(block["pos"]), float(np.max(state["block_half"])), block["yaw"], color=mpl,
                    alpha=0.8)
    elif task == "pusht":
        goal = np.asarray(state["goal_points"])
        ax.scatter(goal[:, 0], goal[:, 1], s=1, color="tab:green", alpha=0.2)
        ax.plot(*np.asarray(state["t_pose"])[:2], marker="s", color="slategray", ms=10)
    ax.plot(*np.asarray(state["tcp"])[:2], marker="o", color="black", ms=6, label="TCP")


def plot_multimodality(policy: Policy, seeds: list[int], out: str | Path) -> Path:
    """Write a figure with one top-view panel per seed (x forward, y left) of the sampled TCP paths."""
    import matplotlib  # noqa: PLC0415

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt  # noqa: PLC0415

    if policy.config.action_space != "ee_position":
        raise ValueError("the top-view plot needs planar ee_position actions")
    fig, axes = plt.subplots(1, len(seeds), figsize=(4 * len(seeds), 4), squeeze=False)
    for ax, seed in zip(axes[0], seeds):
        state, chunks = initial_batch(policy, seed)
        _draw_scene(ax, policy.config.task, state)
        for path in chunks:
            ax.plot(path[:, 0], path[:, 1], color="black", alpha=0.35, lw=1)
            ax.plot(path[-1, 0], path[-1, 1], marker=".", color="black", alpha=0.6)
        ax.set_title(f"{policy.config.task} seed {seed}: B={len(chunks)} chunks (H={chunks.shape[1]})", fontsize=9)
        ax.set_aspect("equal")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out

