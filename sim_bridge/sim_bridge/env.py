"""Factory of task environments: ``make_env(task, scenario, seed)``."""
from __future__ import annotations

from .scenarios import get_scenario
from .tasks import TASKS, TaskEnv


def make_env(task: str, scenario: str = "id", seed: int = 0, images: bool = True) -> TaskEnv:
    """Create the environment of one episode; call ``reset()`` before stepping.

    Args:
        task: ``"sorting"``, ``"stacking"`` or ``"pusht"``.
        scenario: Scenario name of ``scenarios.SCENARIOS[task]``.
        seed: Episode seed; ``(task, scenario, seed)`` determines the episode.
        images: Render the two 96x96 cameras into observations (off: proprio only, faster).
    """
    return TASKS[task](get_scenario(task, scenario), seed, images=images)
