"""The multi-delta threshold fit equals the core's fit_threshold bit for bit, with and without shape curves."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.calibration import CalibrationSettings
from fiper_ros.core.thresholds import GUARANTEED_KINDS, AuthorsBand, ThresholdSettings, fit_threshold
from fiper_ros.evaluation.sweep import DELTAS
from fiper_ros.evaluation.threshold_grid import GRID_KINDS, fit_threshold_grid


def _curves(rng: np.random.Generator, scale: float, count: int) -> list[np.ndarray]:
    return [np.cumsum(rng.random(rng.integers(3, 60))) * scale for _ in range(count)]


@pytest.mark.parametrize("profile", ["paper", "reference"])
@pytest.mark.parametrize("shaped", [False, True], ids=["own-split", "shape-curves"])
@pytest.mark.parametrize("trial", range(6))
def test_grid_equals_fit_threshold(profile: str, shaped: bool, trial: int) -> None:
    rng = np.random.default_rng(trial)
    scale = [1e-3, 1.0, 1e3][trial % 3]
    curves = _curves(rng, scale, int(rng.integers(4, 40)))
    shape = _curves(rng, scale, int(rng.integers(2, 40))) if shaped else None
    if trial == 0:
        curves = [np.ones(10)] * 6  # ties and a zero spread
        shape = [np.ones(12)] * 5 if shaped else None  # longer than every conformal curve
    base = CalibrationSettings(profile=profile, seed=trial).threshold_settings()
    deltas = DELTAS + (0.3,)
    grid = fit_threshold_grid(curves, GRID_KINDS, deltas, base, shape)
    # one threshold per (kind, delta), in order: a truncated grid must not pass with fewer comparisons
    assert list(grid) == list(GRID_KINDS) and len(deltas) == 11 and set(GUARANTEED_KINDS) <= set(GRID_KINDS)
    assert all([t.delta for t in grid[kind]] == list(deltas) for kind in GRID_KINDS)
    infinite = 0
    for kind in GRID_KINDS:
        for threshold in grid[kind]:
            expected = fit_threshold(curves, replace(base, kind=kind, delta=threshold.delta), shape)
            np.testing.assert_array_equal(threshold.values, expected.values, err_msg=f"{kind} {threshold.delta}")
            np.testing.assert_array_equal(threshold.over(80), expected.over(80))
            assert threshold.params == expected.params, (kind, threshold.delta)
            infinite += bool(np.isinf(threshold.values).any())
    if profile == "paper":
        assert infinite > 0  # the small deltas' conformal quantiles of a few curves are +inf: compared too


def test_unknown_kind_is_refused() -> None:
    with pytest.raises(ValueError, match="not swept"):
        fit_threshold_grid([np.ones(3)] * 3, ["gaussian"], [0.1], CalibrationSettings().threshold_settings())


def test_reference_band_grid_follows_the_filter_per_delta() -> None:
    # 43 curves: N1 = 22 and (N1 + 1)(1 - delta) > N1 for delta < 1/23 only, so the authors' filter keeps every
    # I1 curve at delta 0.01..0.04 and filters at 0.05..0.1: the modulation differs between the deltas
    rng = np.random.default_rng(9)
    curves = _curves(rng, 1.0, 43)
    base = ThresholdSettings(kind="cp_band", band_rule="reference", band_sign="lower", conformal=False,
                             extension="mean", min_support=1)
    band = AuthorsBand.of([np.asarray(c, dtype=np.float64) for c in curves])
    assert len({band.kept(delta) for delta in DELTAS}) >= 2
    grid = fit_threshold_grid(curves, ["cp_band"], DELTAS, base)
    for threshold in grid["cp_band"]:
        expected = fit_threshold(curves, replace(base, kind="cp_band", delta=threshold.delta))
        np.testing.assert_array_equal(threshold.values, expected.values)
        assert threshold.params == expected.params
