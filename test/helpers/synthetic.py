"""Synthetic rollouts with a known failure, and a small calibration fitted on them.

ID rollouts: embeddings near the origin, action chunks tightly clustered (low entropy). The failing
rollout drifts out of distribution from ``FAIL_FROM`` on: its embeddings shift and its sampled chunks
spread over many ACE cells, so both windowed scores cross their thresholds a few steps later.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.detectors import DETECTORS
from fiper_ros.core.rnd_oe import RNDConfig
from fiper_ros.core.rollout import Rollout

E, B, H, D, EXEC = 16, 32, 8, 2, 4
LENGTH = 20
FAIL_FROM = 8
TINY_RND = RNDConfig(trunk=(32, 32), head=(32,), out_dim=16, max_epochs=10, batch_size=64, lr=1e-3)
#: ``fiper calibrate`` options of a small, quick observation-only calibration (same-data: 12 successes allow
#: delta 0.1).
OBSERVATION_CALIBRATE = ["--detectors", "rnd_oe", "--same-data", "--threshold", "cp_constant", "--delta", "0.1",
                         "--window-obs", "3", "--max-epochs", "10"]


def make_rollout(seed: int, *, fail: bool = False, length: int = LENGTH) -> Rollout:
    """One rollout; ``fail`` makes it drift out of distribution from step ``FAIL_FROM``."""
    rng = np.random.default_rng(seed)
    embeddings = rng.normal(0.0, 1.0, (length, E)).astype(np.float32)
    base = rng.uniform(-1.0, 1.0, (length, 1, H, D))
    actions = base + rng.normal(0.0, 0.01, (length, B, H, D))
    actions[:, 0, 0, :] = [-1.0, -1.0]  # pin every step's range so R_d is the same in all rollouts
    actions[:, 1, 0, :] = [1.0, 1.0]
    if fail:
        embeddings[FAIL_FROM:] += 6.0
        actions[FAIL_FROM:] = rng.uniform(-1.0, 1.0, (length - FAIL_FROM, B, H, D))
    return Rollout(
        rollout_id=f"synthetic-{seed}{'-fail' if fail else ''}", task="synthetic", scenario="ood" if fail else "id",
        embeddings=embeddings, actions=actions.astype(np.float32), exec_steps=EXEC, success=not fail,
    )


def make_calibration(directory: Path, *, combine: str = "and", threshold: str = "cp_constant",
                     delta: float = 0.1, detectors: tuple[str, ...] = DETECTORS) -> Path:
    """Fit a small calibration of ``detectors`` on 24 synthetic successes (split conformal, the default: 12 fit
    RND-OE and R_d, 12 the thresholds) and save it to ``directory``."""
    rollouts = [make_rollout(seed) for seed in range(24)]
    settings = CalibrationSettings(window=3, threshold=threshold, delta=delta, combine=combine,
                                   rnd=TINY_RND, seed=0, detectors=detectors)
    calibrate(rollouts, settings).save(directory)
    return directory
