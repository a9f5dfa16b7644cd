"""Score aggregation, eqs. (2) and (6)."""

from __future__ import annotations

import numpy as np
import pytest

from fiper_ros.core.window import MODES, WindowAccumulator, aggregate, cumulative, max_pooled, windowed


def test_hand_computed_window() -> None:
    scores = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    assert np.array_equal(windowed(scores, 2), [1.0, 3.0, 5.0, 7.0, 9.0])
    assert np.array_equal(windowed(scores, 3), [1.0, 3.0, 6.0, 9.0, 12.0])
    assert np.array_equal(windowed(scores, 1), scores)


def test_hand_computed_max_pooling() -> None:
    scores = np.array([1.0, 5.0, 2.0, 0.0, 3.0, 1.0])
    assert max_pooled(scores, 2).tolist() == [1.0, 5.0, 5.0, 2.0, 3.0, 3.0]
    assert max_pooled(scores, 3).tolist() == [1.0, 5.0, 5.0, 5.0, 3.0, 3.0]
    assert max_pooled(scores, 1).tolist() == scores.tolist()
    assert max_pooled(scores, 50).tolist() == [1.0, 5.0, 5.0, 5.0, 5.0, 5.0]  # longer than the rollout: running max
    assert aggregate(scores, "max", 2).tolist() == max_pooled(scores, 2).tolist()


def test_window_longer_than_rollout_is_the_cumulative_sum() -> None:
    scores = np.array([0.5, 0.25, 2.0])
    assert np.array_equal(windowed(scores, 50), cumulative(scores))
    assert np.array_equal(cumulative(scores), [0.5, 0.75, 2.75])


def test_aggregate_modes() -> None:
    scores = np.array([1.0, 2.0, 4.0])
    assert np.array_equal(aggregate(scores, "single"), scores)
    assert np.array_equal(aggregate(scores, "window", 2), [1.0, 3.0, 6.0])
    assert np.array_equal(aggregate(scores, "cumulative"), [1.0, 3.0, 7.0])
    with pytest.raises(ValueError, match="mode"):
        aggregate(scores, "median")
    with pytest.raises(ValueError, match="window size"):
        windowed(scores, 0)


@pytest.mark.parametrize(
    ("mode", "w"), [("window", 1), ("window", 4), ("window", 40), ("cumulative", 1), ("single", 1), ("max", 1),
                    ("max", 4), ("max", 40)]
)
def test_streaming_equals_vectorised_bit_for_bit(mode: str, w: int) -> None:
    rng = np.random.default_rng(w)
    accumulator = WindowAccumulator(w, mode)
    for length in (1, 7, 33):
        scores = rng.lognormal(size=length) * 1e3
        accumulator.reset()
        streamed = np.array([accumulator.push(s) for s in scores])
        assert np.array_equal(streamed, aggregate(scores, mode, w))


@pytest.mark.parametrize("mode", MODES)
def test_a_non_finite_score_never_enters_the_window(mode: str) -> None:
    window = WindowAccumulator(3, mode)
    window.push(1.0)
    for bad in (np.nan, np.inf, -np.inf):
        with pytest.raises(ValueError, match="non-finite"):
            window.push(bad)
    assert window.push(2.0) == {"single": 2.0, "max": 2.0}.get(mode, 3.0)  # 1 + 2 (max 2): none of the bad ones stayed
    with pytest.raises(ValueError, match="finite"):
        aggregate(np.array([1.0, np.nan]), mode, 3)


@pytest.mark.parametrize(("mode", "expected"), [("window", 4.0), ("cumulative", 7.0), ("single", 4.0), ("max", 4.0)])
def test_skip_enters_zeros_without_one_push_per_step(mode: str, expected: float) -> None:
    window = WindowAccumulator(3, mode)
    window.push(3.0)
    window.skip(10**15)  # O(w): a loop per skipped step would never return
    assert window.push(4.0) == expected  # the window holds 0, 0, 4 (max 4); the cumulative sum 3 + 4


def test_a_skipped_step_is_a_lower_bound_of_the_max() -> None:
    window = WindowAccumulator(3, "max")
    window.push(2.0)
    window.skip(1)
    assert window.push(1.0) == 2.0  # 2, 0, 1: the 3 still inside the window
    window.skip(2)
    assert window.push(0.5) == 0.5  # 0, 0, 0.5: the 2 left the window
    with pytest.raises(ValueError):
        window.skip(-1)


def test_float32_scores_are_summed_in_float64() -> None:
    # 1e8 + 1 is 1e8 in float32 (24-bit mantissa) but exact in float64, where the thresholds decide.
    scores = np.array([1e8, 1.0], dtype=np.float32)
    for summed in (windowed(scores, 2), cumulative(scores), aggregate(scores, "single")):
        assert summed.dtype == np.float64
    assert windowed(scores, 2).tolist() == [1e8, 100_000_001.0]
    assert cumulative(scores).tolist() == [1e8, 100_000_001.0]


def test_defaults_are_the_single_step_window() -> None:
    scores = np.array([1.0, 2.0, 4.0])
    assert aggregate(scores).tolist() == [1.0, 2.0, 4.0]  # mode "window", w = 1
    window = WindowAccumulator()
    assert (window.mode, window.w) == ("window", 1)
    assert [window.push(s) for s in scores] == [1.0, 2.0, 4.0]


@pytest.mark.parametrize("mode", MODES)
def test_skipping_no_step_changes_nothing(mode: str) -> None:
    window = WindowAccumulator(2, mode)
    window.push(3.0)
    window.skip(0)
    assert window.push(4.0) == {"single": 4.0, "max": 4.0}.get(mode, 7.0)


def test_rejections_say_what_was_wrong() -> None:
    with pytest.raises(ValueError, match=r"^scores must be finite, got 2 NaN/inf$"):  # two of three
        windowed(np.array([1.0, np.nan, np.inf]), 2)
    with pytest.raises(ValueError, match=r"^scores must be 1-D, got shape \(1, 2\)$"):
        cumulative(np.ones((1, 2)))
    with pytest.raises(ValueError, match=r"^unknown aggregation mode 'median'; expected one of \('window', "):
        WindowAccumulator(2, "median")
    with pytest.raises(ValueError, match=r"^cannot skip -1 steps$"):
        WindowAccumulator(2).skip(-1)
