"""A tiny synthetic dataset and engine settings shared by the evaluation tests."""

from __future__ import annotations

import pytest

from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.synthetic import make_task


@pytest.fixture(scope="session")
def tiny_dataset() -> Dataset:
    """Sorting-shaped SYNTHETIC rollouts at a quarter of the size: 12 calibration, 24 test."""
    rollouts = make_task("sorting", seed=3, calibration=12, test=24, scale=0.25)
    return Dataset("sorting", rollouts.calibration, rollouts.test)


@pytest.fixture(scope="session")
def tiny_settings() -> MethodSettings:
    """Tiny networks (fast, numbers meaningless)."""
    return MethodSettings.tiny()
