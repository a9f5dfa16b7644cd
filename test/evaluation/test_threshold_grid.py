"""The multi-delta threshold fit equals the core's fit_threshold bit for bit."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.thresholds import fit_threshold
from fiper_ros.evaluation.sweep import DELTAS
from fiper_ros.evaluation.threshold_grid import GRID_KINDS, fit_threshold_grid


@pytest.mark.parametrize("profile", ["paper", "reference"])
@pytest.mark.parametrize("trial", range(6))
def test_grid_equals_fit_threshold(profile: str, trial: int) -> None:
    rng = np.random.default_rng(trial)
    scale = [1e-3, 1.0, 1e3][trial % 3]
    curves = [np.cumsum(rng.random(rng.integers(3, 60))) * scale for _ in range(int(rng.integers(4, 40)))]
    if trial == 0:
        curves = [np.ones(10)] * 6  # ties and a zero spread
    base = CalibrationSettings(profile=profile, seed=trial).threshold_settings()
    deltas = DELTAS + (0.3,)
    grid = fit_threshold_grid(curves, GRID_KINDS, deltas, base)
    # one threshold per (kind, delta), in order: a truncated grid must not pass with fewer comparisons
    assert list(grid) == list(GRID_KINDS) and len(deltas) == 11
    assert all([t.delta for t in grid[kind]] == list(deltas) for kind in GRID_KINDS)
    for kind in GRID_KINDS:
        for threshold in grid[kind]:
            expected = fit_threshold(curves, replace(base, kind=kind, delta=threshold.delta))
            np.testing.assert_array_equal(threshold.values, expected.values, err_msg=f"{kind} {threshold.delta}")
            np.testing.assert_array_equal(threshold.over(80), expected.over(80))


def test_unknown_kind_is_refused() -> None:
    with pytest.raises(ValueError, match="not swept"):
        fit_threshold_grid([np.ones(3)] * 3, ["gaussian"], [0.1], CalibrationSettings().threshold_settings())
