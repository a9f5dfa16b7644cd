"""Closed-loop, in-process policy rollouts in the MuJoCo tasks (no ROS), recorded as core ``Rollout``s.

Every policy step encodes the last ``T_h`` observations once, samples the whole batch of ``B`` chunks
(FIPER needs all of them) and executes the first ``h`` actions of the first sample, one control step
at a time (so the observation history holds consecutive control steps, as in the demonstrations).
"""
from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass

import numpy as np

from fiper_ros.core.rollout import Rollout
from fiper_ros.policy.noise import sampling_generator
from fiper_ros.policy.policy import Policy

from .env import make_env

LOG = logging.getLogger(__name__)


@dataclass(frozen=True)
class EpisodeResult:
    """Outcome of one closed-loop episode and, if recorded, its rollout."""

    seed: int
    success: bool
    failed: bool
    policy_steps: int
    control_steps: int
    rollout: Rollout | None


def run_episode(policy: Policy, scenario: str, seed: int, record: bool = True, batch: int | None = None,
                max_policy_steps: int | None = None) -> EpisodeResult:
    """Run ``policy`` on the episode ``(task, scenario, seed)`` until success, failure or the time limit.

    Args:
        record: Keep embeddings ``[T, E]`` and action batches ``[T, B, H, D]`` as a core ``Rollout``
            (for ``joint_velocity`` policies with ``metadata["joint_positions"]`` ``[T, 7]``).
        batch: Chunks sampled per policy step (default: the config's ``B``).
        max_policy_steps: Stop earlier than the task's time limit (tests); the result is then no success.
    """
    config = policy.config
    generator = sampling_generator(seed)
    embeddings: list[np.ndarray] = []
    batches: list[np.ndarray] = []
    joints: list[np.ndarray] = []
    steps = 0
    with make_env(config.task, scenario, seed) as env:
        obs = env.reset()
        history = deque([obs], maxlen=config.obs_horizon)
        info = env.info()
        while not env.done and (max_policy_steps is None or steps < max_policy_steps):
            embedding, chunks = policy.act(history, batch, generator)
            if record:
                embeddings.append(embedding)
                batches.append(chunks)
                joints.append(env.arm_qpos().astype(np.float32))
            for action in chunks[0, : config.exec_steps]:
                obs, done, info = env.step(action)
                history.append(obs)
                if done:
                    break
            steps += 1
        control_steps = env.control_step
    LOG.debug("episode %s/%d: success=%s after %d policy steps", scenario, seed, info["success"], steps)
    rollout = None
    if record:
        metadata: dict[str, object] = {"seed": int(seed), "control_steps": int(control_steps)}
        if config.action_space == "joint_velocity":
            metadata["joint_positions"] = np.stack(joints)
        rollout = Rollout(rollout_id=f"{config.task}_{scenario}_{seed:06d}", task=config.task, scenario=scenario,
                          embeddings=np.stack(embeddings), actions=np.stack(batches), exec_steps=config.exec_steps,
                          success=bool(info["success"]), action_space=config.action_space, metadata=metadata)
    return EpisodeResult(int(seed), bool(info["success"]), bool(info["failed"]), steps, int(control_steps), rollout)
