"""STAC: zero for identical consecutive overlaps, growing with a shift between them."""

from __future__ import annotations

import numpy as np
import pytest

from fiper_ros.baselines.base import BaselineError
from fiper_ros.baselines.stac import STAC, stac_scores

H, D, EXEC = 8, 2, 4


def consistent_actions(rng: np.random.Generator, steps: int = 6, samples: int = 12) -> np.ndarray:
    """Each sample follows its own trajectory, so prev[:, h:] == curr[:, :H-h] exactly."""
    trajectories = np.cumsum(rng.normal(size=(samples, steps * EXEC + H, D)), axis=1)
    return np.stack([trajectories[:, t * EXEC : t * EXEC + H] for t in range(steps)])


def test_identical_overlaps_score_zero_and_first_step_is_zero() -> None:
    scores = stac_scores(consistent_actions(np.random.default_rng(0)), EXEC)
    assert scores.shape == (6,)
    assert scores[0] == 0.0
    np.testing.assert_allclose(scores, 0.0, atol=1e-9)


def test_score_grows_with_a_shift_of_the_current_overlap() -> None:
    base = consistent_actions(np.random.default_rng(1))
    means = []
    for shift in (0.0, 0.5, 2.0, 8.0):
        shifted = base.copy()
        shifted[1:, :, : H - EXEC] += shift
        means.append(stac_scores(shifted, EXEC)[1:].mean())
    assert means[0] < 1e-9
    assert all(a < b for a, b in zip(means, means[1:])), means


def test_identical_samples_score_zero_and_bad_shapes_raise() -> None:
    actions = np.ones((4, 5, H, D))
    np.testing.assert_array_equal(stac_scores(actions, EXEC), np.zeros(4))
    with pytest.raises(BaselineError):
        stac_scores(actions, H)
    with pytest.raises(BaselineError):
        stac_scores(actions[0], EXEC)


def test_blocks_give_the_same_scores_as_one_block(monkeypatch: pytest.MonkeyPatch) -> None:
    actions = consistent_actions(np.random.default_rng(2), steps=9)
    actions[4:] += np.random.default_rng(3).normal(size=actions[4:].shape)
    whole = stac_scores(actions, EXEC)
    monkeypatch.setattr("fiper_ros.baselines.stac._BLOCK_ENTRIES", 1)
    np.testing.assert_allclose(stac_scores(actions, EXEC), whole, rtol=1e-12, atol=1e-15)
    assert STAC().fit([], 0).name == "stac"
