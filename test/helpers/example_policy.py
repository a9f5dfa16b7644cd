"""The example policy (``fiper_ros.examples.minimal_policy``) as core rollouts, and a small calibration of it, for
the tests that run the example over DDS."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.rollout import Rollout
from fiper_ros.examples.minimal_policy import EXEC, TASK, StandInPolicy
from helpers.synthetic import TINY_RND

STEPS = 20


def example_rollout(seed: int, *, fail: bool = False, steps: int = STEPS) -> Rollout:
    """The rollout the example publishes for ``seed`` (failing from a third of the way in if ``fail``)."""
    policy = StandInPolicy(seed, steps, steps // 3 if fail else None)
    embeddings, chunks = zip(*(policy.act(t) for t in range(steps)))
    return Rollout(rollout_id=f"example-{seed}", task=TASK, scenario="ood" if fail else "id",
                   embeddings=np.stack(embeddings), actions=np.stack(chunks), exec_steps=EXEC, success=not fail)


def example_calibration(directory: Path) -> Path:
    """A small calibration on 24 successes of the example (split conformal, windows 3, delta 0.1)."""
    settings = CalibrationSettings(window=3, threshold="cp_constant", delta=0.1, rnd=TINY_RND,
                                   seed=0)
    calibrate([example_rollout(1000 + seed) for seed in range(24)], settings).save(directory)
    return directory
