"""Shared fixtures of the FIPER core tests (data from helpers.core_data)."""

from __future__ import annotations

import numpy as np
import pytest

from fiper_ros.core.calibration import Calibration, CalibrationSettings, calibrate
from fiper_ros.core.rollout import Rollout
from helpers.core_data import TINY_RND, make_rollout


@pytest.fixture(scope="session")
def calibration_rollouts() -> list[Rollout]:
    rng = np.random.default_rng(7)
    rollouts = [make_rollout(rng, i) for i in range(24)]
    rollouts.append(make_rollout(rng, 99, ood=True, success=False))  # failures are ignored by calibrate
    return rollouts


@pytest.fixture(scope="session")
def settings() -> CalibrationSettings:
    return CalibrationSettings(rnd=TINY_RND, window=3, delta=0.2, threshold="cp_band")


@pytest.fixture(scope="session")
def calibration(calibration_rollouts: list[Rollout], settings: CalibrationSettings) -> Calibration:
    return calibrate(calibration_rollouts, settings)
