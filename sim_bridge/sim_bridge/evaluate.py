"""Measurements for docs/sim.md: expert success rates and per-control-step simulation / render cost."""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from .env import make_env
from .experts import make_expert, run_expert


@dataclass(frozen=True)
class SuccessRate:
    """Expert outcome over a range of seeds of one scenario."""

    task: str
    scenario: str
    episodes: int
    successes: int
    mean_policy_steps: float
    """Mean episode length of the successful episodes in policy steps (control steps / h)."""

    @property
    def rate(self) -> float:
        """Fraction of successful episodes."""
        return self.successes / self.episodes


def expert_success(task: str, scenario: str, seeds: range) -> SuccessRate:
    """Run the expert (without images) on every seed and count successes."""
    lengths = []
    for seed in seeds:
        with make_env(task, scenario, seed, images=False) as env:
            info = run_expert(env)
            if info["success"]:
                lengths.append(info["control_step"] / env.exec_steps)
    return SuccessRate(task, scenario, len(seeds), len(lengths), float(np.mean(lengths)) if lengths else 0.0)


@dataclass(frozen=True)
class StepCost:
    """Mean wall-clock cost of one control step, split into physics+control and rendering."""

    task: str
    sim_ms: float
    render_ms: float
    build_ms: float


def step_cost(task: str, steps: int = 100, seed: int = 0) -> StepCost:
    """Time up to ``steps`` expert control steps of one ID episode with images.

    ``render_ms`` is the time of one extra ``render()`` (both cameras) per step; ``sim_ms`` is the rest
    of ``step()``: action handling (IK), physics and proprio.
    """
    start = time.perf_counter()
    env = make_env(task, "id", seed)
    build = time.perf_counter() - start
    with env:
        env.reset()
        expert = make_expert(env)
        step_total = render_total = 0.0
        count = 0
        while count < steps and not env.done:
            action = expert.act(env.state())
            t0 = time.perf_counter()
            env.step(action)
            t1 = time.perf_counter()
            env.render()
            step_total += t1 - t0
            render_total += time.perf_counter() - t1
            count += 1
    return StepCost(task, 1e3 * (step_total - render_total) / count, 1e3 * render_total / count, 1e3 * build)
