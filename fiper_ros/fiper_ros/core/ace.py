"""Action-chunk entropy (ACE), eq. (4) and App. A.1.

``s_ACE(A_t) = sum_{i=0}^{H-1} E_hat(a_{t+i|t}^(1..B))``: for every prediction step ``i`` of the
chunk, the ``B`` sampled actions are binned dimension-wise and ``E_hat`` is the Shannon entropy
(bits) of the resulting cell histogram.

Binning (App. A.1): the cell size per dimension is ``alpha * R_d``, ``R_d`` being the range of
dimension ``d`` over the calibration action chunks. For each step the bins of dimension ``d`` start
at the step's sample minimum; there are ``N_d = ceil(range / (alpha R_d))`` of them (at least one),
and a sample lying exactly on the step's maximum belongs to the last bin. A cell is the tuple of the
per-dimension bin indices. A dimension with ``R_d = 0`` (constant over calibration) is treated as a
single bin: it carries no information about uncertainty.

Everything is vectorised over samples and steps, in a ``[D, steps, B]`` layout (each dimension's samples
contiguous: the per-element arithmetic, hence every number, is that of any other layout). The per-dimension
bin indices are combined into one integer code per (step, sample); where every step has few cells (at most
:data:`HISTOGRAM_CELLS_PER_SAMPLE` per sample) the codes are counted in one histogram, else sorted along the
sample axis, the run lengths of equal codes being the counts (codes beyond int64: the index tuples sorted). All
visit a step's cells in ascending code order, so they sum the same terms in the same order: a step's entropy is
the same to the bit whichever way its call counts it (a rollout scored at once counts every step the way its
widest step needs; the streaming monitor one step at a time).

Binning (``binning``, :data:`BINNINGS`): the above is ``"paper"``. ``"reference"`` assigns cells as the authors'
code does, in float32 (the dtype of their stored action predictions): per step and dimension the samples are
rounded to float32, ``low = min - b (max - min)`` and ``high = max + b (max - min)`` (``b`` the range buffer),
the edges are ``np.arange(low, high + cell, cell, dtype=float32)`` with the float32 cell
``float32(alpha) * float32(R_d)`` (:func:`cell_size`), and a sample's bin is ``np.digitize(x, edges) - 1``, the
last edge at or below it. A sample exactly on a float32 edge therefore takes the bin above it, where the float64
``floor`` may put it in the bin below. The edges are not built: the last edge at or below each sample is found
from the float64 estimate ``floor((x - low) / delta)``, checked against ``np.arange``'s float32 arithmetic
for the edge at an index (``low + float32(i) * delta`` with ``delta = (low + cell) - low``) and, where float32
rounded an edge across the sample, by a binary search over the edge index: the work is ``O(B)``, at most
``O(B log N_d)``, whatever the range. As in the paper rule, a dimension with ``R_d = 0`` is one bin; a step
whose edge count overflows (float32, or beyond ``2**62``) has no entropy (NaN; the authors' code raises
there).
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np

from fiper_ros.core.errors import ChoiceError, CoreError

# Mixed-radix cell codes must fit in int64; beyond this many bits we sort index tuples instead. Those
# tuples stay float64 (exact integers): a bin index beyond the int64 range would cast to INT64_MIN and
# put every far-apart sample into one cell (entropy 0, an uncertain batch read as certain).
_MAX_CODE_BITS = 62.0
#: Steps whose cells number at most this many per sample are counted in a histogram (its memory at most this
#: many counts per sample), others by sorting their codes: the two cost the same at about one cell per sample
#: (16 steps of B 256, D 2, hot: 52 against 50 us; at 16 cells per sample 268 against 66 us, at 0.25 35 against 65).
HISTOGRAM_CELLS_PER_SAMPLE = 1
#: How samples are assigned to cells: the paper's float64 ``floor((x - low) / cell)`` or the authors' float32
#: ``np.arange`` edges and ``np.digitize`` (module docstring).
BINNINGS = ("paper", "reference")
# Edge counts at or beyond this cannot be indexed in int64: such a step has no entropy in the reference binning.
_MAX_EDGES = 2.0**62


def check_alpha(alpha: float) -> None:
    """Refuse a cell size factor outside (0, 1) (App. A.1): :class:`~fiper_ros.core.errors.CoreError`."""
    if not 0.0 < alpha < 1.0:
        raise CoreError(f"cell size factor alpha must be in (0, 1), got {alpha}")


def check_binning(binning: str) -> None:
    """Refuse a binning rule that is not one of :data:`BINNINGS`: :class:`~fiper_ros.core.errors.ChoiceError`."""
    if binning not in BINNINGS:
        raise ChoiceError(f"unknown ACE binning {binning!r}; expected one of {BINNINGS}")


def cell_size(ranges: np.ndarray, alpha: float, binning: str = "paper") -> np.ndarray:
    """Cell size ``alpha * R_d`` per action dimension (App. A.1); ``alpha`` in (0, 1).

    ``binning="reference"``: the authors' float32 product ``float32(alpha) * float32(R_d)`` (held exactly in
    the float64 result); ``R_d`` of float32 samples, ``max - min`` in float64, is exact, so its float32 rounding
    is their float32 ``max - min``.
    """
    check_alpha(alpha)
    check_binning(binning)
    ranges = np.asarray(ranges, dtype=np.float64)
    if ranges.ndim != 1 or np.any(~np.isfinite(ranges)) or np.any(ranges < 0):
        raise ValueError(f"ranges must be a finite non-negative vector, got {ranges}")
    if binning == "reference":
        return (np.float32(alpha) * ranges.astype(np.float32)).astype(np.float64)
    return alpha * ranges


def action_ranges(chunks: np.ndarray | Iterable[np.ndarray]) -> np.ndarray:
    """``R_d = max - min`` per dimension over all calibration action chunks (App. A.1).

    Args:
        chunks: One array ``[..., D]`` or an iterable of such arrays (e.g. each rollout's
            ``[T, B, H, D]`` actions); reduced one at a time, so nothing is concatenated.
    """
    arrays = [chunks] if isinstance(chunks, np.ndarray) else chunks
    low: np.ndarray | None = None
    high: np.ndarray | None = None
    for array in arrays:
        flat = np.asarray(array, dtype=np.float64)
        flat = flat.reshape(-1, flat.shape[-1])
        if flat.shape[0] == 0:
            continue
        if low is not None and flat.shape[1] != low.shape[0]:
            raise ValueError(f"action dimension mismatch: {flat.shape[1]} vs {low.shape[0]}")
        a_min, a_max = flat.min(axis=0), flat.max(axis=0)
        low = a_min if low is None else np.minimum(low, a_min)
        high = a_max if high is None else np.maximum(high, a_max)
    if low is None or high is None:
        raise ValueError("action_ranges needs at least one non-empty action array")
    return high - low


def _validated_cell(cell: np.ndarray, dims: int) -> np.ndarray:
    cell = np.asarray(cell, dtype=np.float64)
    if cell.shape != (dims,):
        raise ValueError(f"cell_size must have shape ({dims},), got {cell.shape}")
    if not (np.isfinite(cell).all() and (cell >= 0).all()):
        raise ValueError(f"cell_size must be finite and >= 0, got {cell}")
    return cell


def _run_entropies(starts: np.ndarray, groups: int, samples: int) -> np.ndarray:
    """Entropy per group from a flat mask marking the first element of each run of equal cells."""
    positions = starts.nonzero()[0]
    counts = np.empty_like(positions)  # each run's length: up to the next run's start, the last to the end
    np.subtract(positions[1:], positions[:-1], out=counts[:-1])
    counts[-1] = groups * samples - positions[-1]
    p = counts / samples
    return np.bincount(positions // samples, weights=-p * np.log2(p), minlength=groups)


def _codes(index: np.ndarray, n_bins: np.ndarray) -> np.ndarray:
    """The mixed-radix cell code ``[G, B]`` of the bin indices ``index[D, G, B]`` (``n_bins[D, G]`` per dimension,
    the first dimension least significant); the caller makes sure every code fits in int64."""
    codes = index[0].astype(np.int64)
    stride = np.ones(index.shape[1], dtype=np.int64)
    for d in range(1, index.shape[0]):
        stride = stride * n_bins[d - 1].astype(np.int64)
        codes += index[d].astype(np.int64) * stride[:, None]
    return codes


def _histogram_entropies(index: np.ndarray, n_bins: np.ndarray, cells: int) -> np.ndarray:
    """Entropy per group of the bin indices ``index[D, G, B]`` (``n_bins[D, G]`` per dimension, at most ``cells``
    cells per group): one histogram of the codes, group ``g`` at ``g * cells``; cells in ascending code order."""
    dims, groups, samples = index.shape
    codes = _codes(index, n_bins) + (np.arange(groups, dtype=np.int64) * cells)[:, None]
    counts = np.bincount(codes.ravel(), minlength=groups * cells)
    filled = counts.nonzero()[0]
    p = counts[filled] / samples
    return np.bincount(filled // cells, weights=-p * np.log2(p), minlength=groups)


def _sorted_entropies(index: np.ndarray, n_bins: np.ndarray) -> np.ndarray:
    """Entropy per group of the bin indices ``index[D, G, B]`` by sorting each group's codes (which fit in int64);
    cells in ascending code order, as :func:`_histogram_entropies`."""
    dims, groups, samples = index.shape
    codes = _codes(index, n_bins)
    codes.sort(axis=1)
    starts = np.empty((groups, samples), dtype=bool)
    starts[:, 0] = True
    np.not_equal(codes[:, 1:], codes[:, :-1], out=starts[:, 1:])
    return _run_entropies(starts.ravel(), groups, samples)


def _tuple_entropies(index: np.ndarray) -> np.ndarray:
    """Entropy per group of the bin indices ``index[D, G, B]`` whose codes would not fit in int64: the index
    tuples (exact float64 integers) sorted, the last dimension first, which is ascending code order."""
    dims, groups, samples = index.shape
    rows = index.transpose(1, 2, 0).reshape(groups * samples, dims)
    group_of_row = np.repeat(np.arange(groups), samples)
    order = np.lexsort((*(rows[:, d] for d in range(dims)), group_of_row))  # the last key sorts first
    rows = rows[order]
    starts = np.ones(groups * samples, dtype=bool)
    starts[1:] = np.any(rows[1:] != rows[:-1], axis=1) | (group_of_row[1:] != group_of_row[:-1])
    return _run_entropies(starts, groups, samples)


def _authors_edge(k: np.ndarray, low: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """Edge ``k`` of ``np.arange(low, stop, cell, dtype=float32)``: ``low + float32(k) * delta`` in float32, with
    ``delta = (low + cell) - low`` (numpy's fill of a float32 range; its edge 1, ``low + cell``, is the same
    number: ``test_reference_bins_are_np_arange_and_np_digitize_in_float32``)."""
    return low + k.astype(np.float32) * delta


#: Bin indices ``[D, G, B]`` (exact float64 integers), ``n_bins[D, G]``, the groups without a defined entropy and
#: the most cells of a group.
Bins = tuple[np.ndarray, np.ndarray, np.ndarray, float]


def _authors_bins(x: np.ndarray, cell: np.ndarray, range_buffer: float) -> Bins:
    """The reference binning (module docstring) of ``x[D, G, B]``."""
    informative = (cell > 0)[:, None]
    step = np.where(informative, cell.astype(np.float32)[:, None], np.float32(1.0))
    with np.errstate(over="ignore", invalid="ignore"):
        x32 = x.astype(np.float32)
        low, high = x32.min(axis=2), x32.max(axis=2)
        pad = np.float32(range_buffer) * (high - low)
        low, high = low - pad, high + pad
        edges = np.ceil(((high + step) - low) / step, dtype=np.float64)  # np.arange's length: float32, then ceil
        undefined = ~((edges < _MAX_EDGES) | ~informative).all(axis=0)
        edges = np.where(informative & ~undefined, np.maximum(edges, 1.0), 1.0)
        delta = (low + step) - low
    low3, delta3, last = low[:, :, None], delta[:, :, None], (edges - 1).astype(np.int64)[:, :, None]
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero delta (every edge is low): searched below
        guess = np.floor((x32 - low3.astype(np.float64)) / delta3)
    index = np.where(guess >= 0, np.minimum(guess, last), 0).astype(np.int64)  # NaN compares False: 0
    # The guess is the cell unless float32 rounded an edge across the sample: search those (np.digitize's answer,
    # the last edge at or below the sample, is where one edge is at or below it and the next above it).
    wrong = (_authors_edge(index, low3, delta3) > x32) | (
        (index < last) & (_authors_edge(index + 1, low3, delta3) <= x32))
    if wrong.any():
        every = [np.broadcast_to(a, x.shape)[wrong] for a in (x32, low3, delta3, last)]
        index[wrong] = _last_edge_at_or_below(*every)
    return index.astype(np.float64), edges, undefined, float(edges.prod(axis=0).max())


def _last_edge_at_or_below(x: np.ndarray, low: np.ndarray, delta: np.ndarray, last: np.ndarray) -> np.ndarray:
    """Per sample, the largest edge index ``k <= last`` with edge ``k`` at or below the sample (edge 0, ``low``, is):
    a binary search over the monotone edges of :func:`_authors_edge`."""
    below = np.zeros(x.shape, dtype=np.int64)
    above = last.copy()
    for _ in range(int(last.max()).bit_length()):
        middle = (below + above + 1) // 2
        at_or_below = _authors_edge(middle, low, delta) <= x
        below = np.where(at_or_below, middle, below)
        above = np.where(at_or_below, above, middle - 1)
    return below


def _paper_bins(x: np.ndarray, cell: np.ndarray, range_buffer: float) -> Bins:
    """The paper's binning of ``x[D, G, B]`` (in place)."""
    low = x.min(axis=2)
    span = x.max(axis=2) - low
    if range_buffer:
        pad = range_buffer * span
        low = low - pad
        span = span + 2.0 * pad
    informative = (cell > 0)[:, None]
    safe_cell = np.where(informative, cell[:, None], 1.0)
    with np.errstate(over="ignore"):
        n_bins = np.where(informative, np.maximum(np.ceil(span / safe_cell), 1.0), 1.0)
        index = np.subtract(x, low[:, :, None], out=x)  # in place: the batch is not needed after this
        np.divide(index, safe_cell[:, :, None], out=index)
        np.floor(index, out=index)
        # A step whose range is more cells wide than float64 can count has no defined entropy: NaN, which
        # the score's finiteness check turns into a rejected step (fiper_ros.core.scores.NonFiniteScore).
        undefined = ~np.isfinite(n_bins).all(axis=0)
        if undefined.any():
            n_bins[:, undefined] = 1.0
            index[:, undefined] = 0.0
        np.minimum(index, (n_bins - 1)[:, :, None], out=index)
        cells = float(n_bins.prod(axis=0).max())
    return index, n_bins, undefined, cells


def _grouped_entropies(x: np.ndarray, cell: np.ndarray, range_buffer: float,
                       histogram_cells: float = HISTOGRAM_CELLS_PER_SAMPLE, binning: str = "paper") -> np.ndarray:
    """Binned entropy (bits) of each group of samples ``x[D, G, B]``, a float64 array this function may overwrite
    (``histogram_cells``: the histogram's bound, :data:`HISTOGRAM_CELLS_PER_SAMPLE`; 0 sorts always)."""
    samples = x.shape[2]
    bins = _paper_bins if binning == "paper" else _authors_bins
    index, n_bins, undefined, cells = bins(x, cell, range_buffer)
    if cells <= histogram_cells * samples:
        entropies = _histogram_entropies(index, n_bins, int(cells))
    elif float(np.log2(n_bins).sum(axis=0).max()) < _MAX_CODE_BITS:
        entropies = _sorted_entropies(index, n_bins)  # every index < 2**62 here
    else:
        entropies = _tuple_entropies(index)
    entropies[undefined] = np.nan
    return entropies


def step_entropies(actions: np.ndarray, cell_size: np.ndarray, range_buffer: float = 0.0,
                   binning: str = "paper") -> np.ndarray:
    """Per-step entropies ``E_hat`` (bits) of action batches ``[..., B, H, D]`` -> ``[..., H]``.

    Args:
        actions: Sampled action chunks; any leading batch axes (e.g. rollout steps ``T``).
        cell_size: ``alpha * R_d``, shape ``[D]``; a zero entry makes that dimension one bin.
        range_buffer: Widen each step's sample range by this fraction on both sides before
            binning. ``0`` is the paper's definition; the reference profile uses ``0.01``
            (see :mod:`fiper_ros.core.profiles`).
        binning: ``"paper"`` or ``"reference"`` (the authors' float32 edges, module docstring; the reference
            profile's, with the cell of :func:`cell_size` ``binning="reference"``).
    """
    x = np.asarray(actions)
    if x.ndim < 3:
        raise ValueError(f"actions must be [..., B, H, D], got shape {x.shape}")
    *lead, samples, horizon, dims = x.shape
    if samples < 1 or horizon < 1 or dims < 1:
        raise ValueError(f"actions have an empty axis: shape {x.shape}")
    if not np.isfinite(x).all():  # in float64 as in float32 or any other dtype: the conversion keeps finiteness
        raise ValueError("actions contain NaN/inf")
    cell = _validated_cell(cell_size, dims)
    check_binning(binning)
    # One copy, in float64 and the [D, steps, B] layout at once, which the counting may overwrite.
    last = x.ndim - 1
    grouped = np.array(x.transpose(last, *range(last - 2), last - 1, last - 2), dtype=np.float64, order="C")
    return _grouped_entropies(grouped.reshape(dims, -1, samples), cell, range_buffer,
                              binning=binning).reshape(*lead, horizon)


def ace_score(actions: np.ndarray, cell_size: np.ndarray) -> float:
    """ACE score of one action-chunk batch ``[B, H, D]``: sum over ``H`` of entropies in bits (eq. 4)."""
    actions = np.asarray(actions)
    if actions.ndim != 3:
        raise ValueError(f"actions must be [B, H, D], got shape {actions.shape}")
    return float(step_entropies(actions, cell_size).sum())
