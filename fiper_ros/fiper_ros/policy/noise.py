"""The sampling noise of a rollout: one generator per episode seed, shared by every way of running a policy.

The in-process loop (``sim_bridge.closed_loop.run_episode``), the multimodality figure and the ROS ``policy_node``
draw their noise from :func:`sampling_generator`, so the same seed gives the same sampled chunks
whether the policy runs in process or over ROS (the node uses the seed in a bridge rollout id's low
32 bits). Kept apart from ``rollout.py`` so the node does not import the simulator.
"""
from __future__ import annotations

import torch

#: Offset of the noise seed from the episode seed (the episode's layout draws from the seed itself).
SEED_OFFSET = 7_919


def sampling_generator(seed: int) -> torch.Generator:
    """The policy's noise stream of the episode with ``seed`` (rollouts are reproducible per seed)."""
    return torch.Generator().manual_seed(int(seed) + SEED_OFFSET)
