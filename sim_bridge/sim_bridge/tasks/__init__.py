"""Task environments: Sorting, Stacking (Stacking-1) and PushT."""
from .base import Obs, TaskEnv
from .pusht import PushTEnv
from .sorting import SortingEnv
from .stacking import StackingEnv

TASKS: dict[str, type[TaskEnv]] = {cls.name: cls for cls in (SortingEnv, StackingEnv, PushTEnv)}
"""Task name -> environment class."""

__all__ = ["TASKS", "Obs", "PushTEnv", "SortingEnv", "StackingEnv", "TaskEnv"]
