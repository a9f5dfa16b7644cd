"""ACE score, eq. (5) and App. A.1: hand-computed cases and a brute-force cross-check."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core import ace
from fiper_ros.core.ace import action_ranges, ace_score, cell_size, step_entropies
from fiper_ros.core.errors import ChoiceError, CoreError


def _two_cells(horizon: int) -> np.ndarray:
    actions = np.zeros((4, horizon, 2))
    actions[2:, :, 0] = 1.0  # two samples per cell along dim 0, dim 1 constant
    return actions


def test_two_equal_cells_give_one_bit_per_step() -> None:
    assert ace_score(_two_cells(5), np.array([0.5, 0.5])) == 5.0


def test_k_equally_filled_cells_give_log2_k() -> None:
    for k in (3, 4, 7):
        actions = np.repeat(np.arange(k, dtype=float), 3)[:, None, None]  # 3 samples in each of k cells
        assert ace_score(actions, np.array([0.5])) == pytest.approx(math.log2(k), abs=1e-12)


def test_identical_samples_give_zero() -> None:
    actions = np.broadcast_to(np.array([0.3, -1.0, 2.0]), (16, 6, 3))
    assert ace_score(actions, np.array([0.1, 0.1, 0.1])) == 0.0


def test_single_sample_gives_zero() -> None:
    actions = np.random.default_rng(0).normal(size=(1, 8, 3))
    assert ace_score(actions, np.full(3, 0.01)) == 0.0


def test_sample_on_the_maximum_joins_the_last_bin() -> None:
    # range 1.0, cell 0.5 -> 2 bins; 0.5 starts bin 1 and the max 1.0 stays in bin 1
    actions = np.array([0.0, 0.5, 1.0, 1.0])[:, None, None]
    assert ace_score(actions, np.array([0.5])) == pytest.approx(-(0.25 * math.log2(0.25) + 0.75 * math.log2(0.75)))


def test_zero_range_dimension_is_a_single_bin() -> None:
    rng = np.random.default_rng(1)
    actions = rng.normal(size=(32, 4, 2))
    only_first = ace_score(actions[:, :, :1], np.array([0.2]))
    assert ace_score(actions, np.array([0.2, 0.0])) == only_first
    assert only_first > 0


def test_cells_are_joint_over_dimensions() -> None:
    # Each dimension alone splits 2/2, jointly the 4 samples sit in 4 different cells -> 2 bits.
    actions = np.array([[0.0, 0.0], [0.0, 1.0], [1.0, 0.0], [1.0, 1.0]])[:, None, :]
    assert ace_score(actions, np.array([0.5, 0.5])) == 2.0


def test_permutation_invariance() -> None:
    rng = np.random.default_rng(2)
    actions = rng.normal(size=(64, 16, 3))
    cell = np.full(3, 0.3)
    assert ace_score(actions[rng.permutation(64)], cell) == ace_score(actions, cell)


def _brute_force(actions: np.ndarray, cell: np.ndarray, buffer: float = 0.0) -> float:
    total = 0.0
    for i in range(actions.shape[1]):
        step = actions[:, i, :]
        low, high = step.min(axis=0), step.max(axis=0)
        low, high = low - buffer * (high - low), high + buffer * (high - low)
        keys = []
        for sample in step:
            key = []
            for d, value in enumerate(sample):
                if cell[d] == 0:
                    key.append(0)
                    continue
                bins = max(math.ceil((high[d] - low[d]) / cell[d]), 1)
                key.append(min(math.floor((value - low[d]) / cell[d]), bins - 1))
            keys.append(tuple(key))
        _, counts = np.unique(np.array(keys), axis=0, return_counts=True)
        p = counts / len(keys)
        total += float(-(p * np.log2(p)).sum())
    return total


@pytest.mark.parametrize("seed", range(6))
def test_matches_brute_force(seed: int) -> None:
    rng = np.random.default_rng(seed)
    samples, horizon, dims = int(rng.integers(1, 40)), int(rng.integers(1, 6)), int(rng.integers(1, 8))
    actions = rng.normal(size=(samples, horizon, dims))
    cell = rng.uniform(0.05, 1.0, size=dims)
    cell[rng.random(dims) < 0.2] = 0.0
    assert ace_score(actions, cell) == pytest.approx(_brute_force(actions, cell), abs=1e-9)
    assert step_entropies(actions, cell, 0.01).sum() == pytest.approx(_brute_force(actions, cell, 0.01), abs=1e-9)


def test_huge_cell_counts_use_the_tuple_path() -> None:
    # 12 dims with ~1e4 bins each overflow int64 codes; every sample is then its own cell.
    actions = np.random.default_rng(3).normal(size=(64, 2, 12))
    assert ace_score(actions, np.full(12, 1e-4)) == pytest.approx(2 * math.log2(64))


def test_rollout_scores_equal_per_step_scores() -> None:
    # the entropies of a whole rollout [T, B, H, D] at once (the offline path, core.scores.act_scores) equal
    # those of each step's batch alone (the streaming path)
    rng = np.random.default_rng(4)
    actions = rng.normal(size=(10, 30, 16, 5)).astype(np.float32)
    cell = np.full(5, 0.4)
    per_step = np.array([ace_score(a, cell) for a in actions])
    assert np.array_equal(step_entropies(actions, cell).sum(axis=-1), per_step)


def test_ranges_and_cell_size() -> None:
    chunks = [np.array([[[0.0, 1.0]], [[2.0, -1.0]]]), np.array([[[-1.0, 0.5]]])]
    assert np.array_equal(action_ranges(chunks), [3.0, 2.0])
    assert np.allclose(cell_size(np.array([3.0, 2.0]), 0.1), [0.3, 0.2])
    with pytest.raises(CoreError, match="alpha"):
        cell_size(np.array([1.0]), 1.5)
    with pytest.raises(ValueError, match="at least one"):
        action_ranges([])


def test_bad_inputs_raise() -> None:
    with pytest.raises(ValueError, match=r"\[B, H, D\]"):
        ace_score(np.zeros((4, 3)), np.ones(3))
    with pytest.raises(ValueError, match="shape"):
        ace_score(np.zeros((4, 3, 2)), np.ones(3))
    with pytest.raises(ValueError, match="NaN"):
        ace_score(np.full((4, 3, 1), np.nan), np.ones(1))


def test_samples_spread_beyond_the_int64_range_of_bin_indices_are_still_counted_apart() -> None:
    # Issue #27: 32 samples spread over 1e30 with 0.01 cells are 1e32 bins apart; the old code cast the bin
    # indices to int64 (INT64_MIN for all), put every sample in one cell and reported entropy 0 (certain).
    actions = np.arange(32, dtype=np.float64)[:, None, None] * np.array([1e30, 0.0])  # [B=32, H=1, D=2]
    assert step_entropies(actions, np.array([0.01, 0.5])) == pytest.approx([5.0])  # log2(32): all apart


def test_a_range_wider_than_float64_can_count_has_no_entropy() -> None:
    actions = np.zeros((4, 2, 2))
    actions[::2, 0, 0], actions[1::2, 0, 0] = -3e38, 3e38
    entropies = step_entropies(actions, np.array([1e-300, 0.5]))
    assert np.isnan(entropies[0]) and entropies[1] == 0.0


@st.composite
def _bin_indices(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray]:
    """Bin indices ``[D, G, B]`` (exact float64 integers) and their ``n_bins[D, G]``."""
    dims, groups, samples = draw(st.integers(1, 4)), draw(st.integers(1, 5)), draw(st.integers(1, 40))
    n_bins = np.asarray(draw(st.lists(st.integers(1, 6), min_size=dims * groups, max_size=dims * groups)),
                        dtype=np.float64).reshape(dims, groups)
    seed = draw(st.integers(0, 2**32 - 1))
    index = np.floor(np.random.default_rng(seed).random((dims, groups, samples)) * n_bins[:, :, None])
    return index, n_bins


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(_bin_indices())
def test_the_histogram_the_sorted_codes_and_the_tuples_give_the_same_entropies_to_the_bit(
        indices: tuple[np.ndarray, np.ndarray]) -> None:
    # Issue #24: the histogram counts most steps; the three ways must sum the same terms in the same order, or a
    # step's score would depend on how many cells its batch spans.
    index, n_bins = indices
    cells = int(n_bins.prod(axis=0).max())
    histogram = ace._histogram_entropies(index, n_bins, cells)
    assert np.array_equal(histogram, ace._sorted_entropies(index, n_bins))
    assert np.array_equal(histogram, ace._tuple_entropies(index))


def test_a_step_spanning_more_cells_than_the_histogram_takes_is_sorted_to_the_same_entropy() -> None:
    rng = np.random.default_rng(5)
    actions = rng.normal(size=(64, 4, 3)) * np.array([1.0, 10.0, 100.0])  # some steps beyond 4 cells per sample
    cell = np.full(3, 0.05)
    x = np.moveaxis(np.moveaxis(actions, -1, 0), -2, -1).reshape(3, -1, 64)
    sorted_always = ace._grouped_entropies(x, cell, 0.01, histogram_cells=0)
    assert np.array_equal(step_entropies(actions, cell, 0.01), sorted_always)
    assert step_entropies(actions, cell, 0.01).sum() == pytest.approx(_brute_force(actions, cell, 0.01), abs=1e-9)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_the_callers_actions_are_left_as_they_were(dtype: type) -> None:
    # The counting overwrites its float64 [D, steps, B] copy in place (issue #24): never the caller's array, also
    # where the layouts would have let numpy hand out a view of it (one dimension, one step).
    rng = np.random.default_rng(6)
    for shape in [(64, 4, 3), (64, 1, 1), (3, 64, 1, 1)]:
        actions = rng.normal(size=shape).astype(dtype)
        before = actions.copy()
        step_entropies(actions, np.full(shape[-1], 0.2), 0.01)
        assert np.array_equal(actions, before)


# The authors' binning (binning="reference"): float32 np.arange edges and np.digitize.
def test_a_sample_on_a_float32_edge_takes_the_upper_cell_where_float64_takes_the_lower() -> None:
    # Samples 0, e, 1 with cell 0.25 and the 1 % buffer. float32: low = 0 - float32(0.01) * 1 = -0.0099999998,
    # edge 1 = float32(low + 0.25) = 0.23999999463558197 = e, so np.digitize puts e in cell 1: three cells.
    # float64: low = -0.01 and (e + 0.01) / 0.25 = 0.99999998 floors to cell 0, with the sample 0: two cells.
    edge = float(np.float32(np.float32(0.0) - np.float32(0.01)) + np.float32(0.25))
    assert edge == 0.23999999463558197
    actions = np.array([0.0, edge, 1.0])[:, None, None]
    assert step_entropies(actions, np.array([0.25]), 0.01)[0] == pytest.approx(-(2 / 3) * math.log2(2 / 3)
                                                                               - (1 / 3) * math.log2(1 / 3))
    assert step_entropies(actions, np.array([0.25]), 0.01, "reference")[0] == pytest.approx(math.log2(3))


def test_the_reference_cell_is_the_float32_product() -> None:
    # float32(0.03) = 0.029999999329447746; float32(0.03) * 2 in float32 is twice that
    np.testing.assert_array_equal(cell_size(np.array([1.0, 2.0]), 0.03, "reference"),
                                  [0.029999999329447746, 0.05999999865889549])
    np.testing.assert_array_equal(cell_size(np.array([1.0, 2.0]), 0.03), [0.03, 0.06])
    with pytest.raises(ChoiceError, match="binning"):
        cell_size(np.array([1.0]), 0.03, "float32")
    with pytest.raises(ChoiceError, match="binning"):
        step_entropies(np.zeros((2, 1, 1)), np.array([0.1]), 0.0, "float32")


def test_reference_binning_keeps_a_zero_cell_one_bin_and_refuses_an_uncountable_range() -> None:
    rng = np.random.default_rng(7)
    actions = rng.normal(size=(32, 4, 2)).astype(np.float32)
    only_first = step_entropies(actions[:, :, :1], np.array([0.2]), 0.01, "reference")
    np.testing.assert_array_equal(step_entropies(actions, np.array([0.2, 0.0]), 0.01, "reference"), only_first)
    wide = np.zeros((4, 2, 1))
    wide[::2, 0, 0], wide[1::2, 0, 0] = -3e38, 3e38  # (high + cell - low) / cell overflows float32
    entropies = step_entropies(wide, np.array([1e-30]), 0.0, "reference")
    assert np.isnan(entropies[0]) and entropies[1] == 0.0


def _edges(samples: np.ndarray, cell: np.float32, buffer: float) -> np.ndarray:
    """The authors' cell edges of one dimension's float32 samples, literally with np.arange (none for cell 0)."""
    low, high = samples.min(), samples.max()
    pad = np.float32(buffer) * (high - low)
    return np.arange(low - pad, high + pad + cell, cell, dtype=np.float32) if cell else np.zeros(0, np.float32)


def _digitized(samples: np.ndarray, cell: np.float32, buffer: float) -> np.ndarray:
    """The authors' cells of one dimension's float32 samples: np.digitize over :func:`_edges`, minus 1; an
    empty np.arange (zero width, or the single bin of cell 0) puts every sample in one cell."""
    edges = _edges(samples, cell, buffer)
    return np.digitize(samples, edges) - 1 if edges.shape[0] else np.zeros(samples.shape[0], dtype=np.int64)


@st.composite
def _float32_steps(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, float]:
    """Samples ``[D, G, B]`` (float32 values), cells (float32 values, some 0) and a range buffer."""
    dims, groups, samples = draw(st.integers(1, 3)), draw(st.integers(1, 4)), draw(st.integers(1, 40))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    scale, offset = 10.0 ** rng.uniform(-3, 2), rng.normal() * 10.0 ** rng.uniform(-2, 4)
    x = rng.normal(size=(dims, groups, samples)) * scale + offset
    if draw(st.booleans()):  # values on a coarse grid: repeated samples and samples on edges
        x = np.round(x / scale * 4) * scale / 4
    cell = (np.abs(rng.normal(size=dims)) * scale * 10.0 ** rng.uniform(-2, 0.5, size=dims)).astype(np.float32)
    cell[rng.random(dims) < 0.2] = 0.0
    x, buffer = x.astype(np.float32), draw(st.sampled_from([0.0, 0.01]))
    if draw(st.booleans()):  # samples on an edge or one float32 step beside it (the smallest and largest stay)
        for d, g in np.ndindex(dims, groups):
            edges = _edges(x[d, g], np.float32(cell[d]), buffer)
            inner = np.setdiff1d(np.arange(samples), [x[d, g].argmin(), x[d, g].argmax()])
            inside = edges[(edges > x[d, g].min()) & (edges < x[d, g].max())]
            if inner.size and inside.size:
                moved = rng.choice(inside, size=inner.size)
                x[d, g, inner] = np.nextafter(moved, moved + rng.integers(-1, 2, size=inner.size).astype(np.float32))
    return x.astype(np.float64), cell.astype(np.float64), buffer


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(_float32_steps())
def test_reference_bins_are_np_arange_and_np_digitize_in_float32(steps: tuple[np.ndarray, np.ndarray, float]) -> None:
    x, cell, buffer = steps
    index, _, undefined, _ = ace._authors_bins(x.copy(), cell, buffer)
    assert not undefined.any()
    for d in range(x.shape[0]):
        for g in range(x.shape[1]):
            literal = _digitized(x[d, g].astype(np.float32), np.float32(cell[d]), buffer)
            np.testing.assert_array_equal(index[d, g], literal, err_msg=f"dimension {d}, group {g}")
