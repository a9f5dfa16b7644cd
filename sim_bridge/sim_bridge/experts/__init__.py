"""Scripted experts with privileged state, one per task: ``make_expert(env)``."""
from __future__ import annotations

from typing import Protocol

import numpy as np

from ..tasks import TaskEnv
from .pusht import PushTExpert
from .sorting import SortingExpert
from .stacking import StackingExpert


class Expert(Protocol):
    """An expert maps the privileged ``env.state()`` to the next action of the task's action space."""

    def act(self, state: dict) -> np.ndarray:
        """Next action."""


def make_expert(env: TaskEnv) -> Expert:
    """Create the task's expert; its mode choices (Sorting's block order, PushT's contact side) follow ``env.seed``."""
    if env.name == "sorting":
        return SortingExpert(env.seed)
    if env.name == "stacking":
        return StackingExpert(env.model, env.control_hz)
    if env.name == "pusht":
        return PushTExpert(env.seed)
    raise KeyError(f"no expert for task {env.name!r}")


def run_expert(env: TaskEnv) -> dict:
    """Reset ``env``, run its expert until the episode ends and return the final ``info``."""
    env.reset()
    expert = make_expert(env)
    while not env.done:
        env.step(expert.act(env.state()))
    return env.info()


__all__ = ["Expert", "PushTExpert", "SortingExpert", "StackingExpert", "make_expert", "run_expert"]
