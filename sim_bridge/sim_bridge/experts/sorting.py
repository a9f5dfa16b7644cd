"""Scripted Sorting expert: push the blocks one after the other into their boxes.

The block order is drawn from the episode seed (the task's multimodality). For the current block the
expert plans a path around all blocks to a point behind the block on the line towards its box centre,
then pushes along that line, re-aiming every control step; once the block is near the box centre it
backs off and turns to the next block.
"""
from __future__ import annotations

from typing import Any

import numpy as np

from ..planar import Rect, follow_path, plan_path, step_towards
from ..tasks.planar import clip_to_workspace, in_workspace
from ..tasks.sorting import COLORS

PUSHER_RADIUS = 0.02
"""Planning radius of the closed finger pads [m]."""
APPROACH_STEP = 0.025
PUSH_STEP = 0.015
PUSH_DEPTH = 0.02
"""How far beyond the contact point the pusher aims while pushing [m]."""
DONE_RADIUS = 0.025
RETREAT = 0.06


class SortingExpert:
    """Privileged-state expert of the Sorting task; ``act(state)`` returns the next planar TCP target."""

    def __init__(self, seed: int) -> None:
        """Draw the block order from ``seed``."""
        rng = np.random.default_rng([seed, 1])
        self.order = list(COLORS) if rng.random() < 0.5 else list(COLORS[::-1])
        self._retreat_to: np.ndarray | None = None
        self._current: str | None = None
        self._direction = np.zeros(2)

    def act(self, state: dict[str, Any]) -> np.ndarray:
        """Next action for the privileged ``state`` of ``SortingEnv.state()``."""
        pusher = state["ee_cmd"]
        if self._retreat_to is not None:
            if np.linalg.norm(self._retreat_to - pusher) > 1e-3:
                return step_towards(pusher, self._retreat_to, APPROACH_STEP)
            self._retreat_to = None
        remaining = [
            c for c in self.order
            if np.linalg.norm(state["blocks"][c]["pos"][:2] - state["boxes"][c]) > DONE_RADIUS
        ]
        color = remaining[0] if remaining else None
        if color != self._current:
            # The current block arrived: back off along the last push direction first.
            if self._current is not None:
                self._retreat_to = clip_to_workspace(pusher - RETREAT * self._direction)
            self._current = color
            return self.act(state)
        if color is None:
            return pusher.copy()
        block = state["blocks"][color]["pos"][:2]
        goal = state["boxes"][color]
        direction = (goal - block) / np.linalg.norm(goal - block)
        self._direction = direction
        half = state["block_half"]
        contact = half + PUSHER_RADIUS
        rel = pusher - block
        along = -float(rel @ direction)
        lateral = float(rel[0] * direction[1] - rel[1] * direction[0])
        if contact - 0.015 <= along <= contact + 0.035 and abs(lateral) < 0.5 * half:
            target = block - direction * (contact - PUSH_DEPTH)
            return step_towards(pusher, target, PUSH_STEP)
        behind = block - direction * (contact + 0.025)
        obstacles = [
            Rect(state["blocks"][c]["pos"][:2], np.full(2, state["block_half"]), state["blocks"][c]["yaw"])
            for c in COLORS
        ]
        path = plan_path(pusher, behind, obstacles, PUSHER_RADIUS + 0.008, in_workspace)
        return follow_path(pusher, path, APPROACH_STEP)
