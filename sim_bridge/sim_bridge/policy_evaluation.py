"""Success rates of a policy over seeded episodes of one scenario, optionally saved as a ``RolloutSet``."""
from __future__ import annotations

import logging
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fiper_ros.core.rollout import RolloutSet
from fiper_ros.policy.policy import Policy

from .closed_loop import EpisodeResult, run_episode

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class EvaluationResult:
    """Episodes of one (task, scenario) evaluation."""

    task: str
    scenario: str
    episodes: list[EpisodeResult]

    @property
    def success_rate(self) -> float:
        """Fraction of successful episodes."""
        return float(np.mean([e.success for e in self.episodes])) if self.episodes else float("nan")

    @property
    def mean_policy_steps(self) -> float:
        """Mean policy steps of the successful episodes (nan if none)."""
        steps = [e.policy_steps for e in self.episodes if e.success]
        return float(np.mean(steps)) if steps else float("nan")


def evaluate(policy: Policy, scenario: str, seeds: Iterable[int], record: bool = False,
             progress: Callable[[int, EpisodeResult], None] | None = None) -> EvaluationResult:
    """Run one closed-loop episode per seed; ``progress`` is called after each one."""
    episodes = []
    for index, seed in enumerate(seeds):
        result = run_episode(policy, scenario, seed, record=record)
        episodes.append(result)
        if progress is not None:
            progress(index, result)
    return EvaluationResult(policy.config.task, scenario, episodes)


def save_rollouts(results: Iterable[EvaluationResult], path: str | Path, split: str = "test") -> RolloutSet:
    """Write the recorded rollouts of ``results`` into the ``split`` ("test" or "calibration") of a ``RolloutSet``."""
    if split not in ("test", "calibration"):
        raise ValueError(f"split must be 'test' or 'calibration', got {split!r}")
    rollouts = [e.rollout for r in results for e in r.episodes if e.rollout is not None]
    rollout_set = RolloutSet(**{split: rollouts})
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    rollout_set.save_npz(path)
    LOG.info("wrote %d rollouts to %s (%s split)", len(rollouts), path, split)
    return rollout_set
