"""Core thresholds for many deltas at once, bit-identical to :func:`fiper_ros.core.thresholds.fit_threshold`.

The sweep fits every (stream, window, kind) threshold for ten deltas. Only a conformal quantile (CP
constant, CP band) or the per-step quantile level (time-varying, and the shape of CP scaled) depends on
delta, so the delta-independent statistics are computed once with the core's own helpers:

- ``cp_constant``: the per-rollout maxima, then one quantile per delta;
- ``cp_band``: the core's :func:`band_statistics` once, then ``k`` per delta; with the reference band rule
  the core's :class:`AuthorsBand` (split, ``mu``, deviations) once, its filter per delta, and its modulation
  and band scores once per distinct kept set (the filter is the only other use of delta);
- ``time_varying``: the per-step quantiles for all levels at once: the calibration curves are sorted
  per step once and numpy's linear interpolation (the core's ``np.nanquantile``) is applied to the
  non-NaN order statistics with numpy's own float operations, vectorised over steps and levels;
- ``cp_scaled``: the per-step quantiles ``q(t)`` of the shape curves for all levels at once (as for
  ``time_varying``), then per delta the core's floor, scores ``max_t eta_i(t) / q(t)`` and ``k``.

``shape_curves`` is the core's: the fit part's curves, ``I1`` of the band kinds (every given curve is
then in ``I2``); ``None`` splits ``I1`` off the given curves, seeded, as the core does.

``test/evaluation/test_threshold_grid.py`` checks the equality with ``fit_threshold`` (values and
parameters) for every kind, both profiles' settings, with and without shape curves, and ragged curves.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fiper_ros.core.thresholds import (
    AuthorsBand,
    BandStatistics,
    Threshold,
    ThresholdSettings,
    _carried,
    _floored,
    _padded,
    _quantile,
    _shape_and_conformal,
    _supported_length,
    _validated,
    band_statistics,
)

GRID_KINDS = ("cp_constant", "cp_band", "time_varying", "cp_scaled")


def _linear_quantiles(sorted_head: np.ndarray, counts: np.ndarray, levels: np.ndarray) -> np.ndarray:
    """numpy's ``"linear"`` quantile of the first ``counts[j]`` sorted values of every column ``j``.

    The same float operations as numpy's ``_quantile`` (virtual index ``(n - 1) q``, neighbours,
    ``_lerp``), vectorised over columns and levels: ``[len(levels), columns]``.
    """
    top = (counts - 1)[None, :]
    virtual = top * levels[:, None]
    previous = np.floor(virtual)
    above = virtual >= top
    lower = np.where(above, top, previous).astype(np.intp)
    upper = np.where(above, top, previous + 1).astype(np.intp)
    gamma = virtual - np.where(above, -1, lower)
    columns = np.arange(sorted_head.shape[1])[None, :]
    a, b = sorted_head[lower, columns], sorted_head[upper, columns]
    diff = b - a
    return np.where(gamma >= 0.5, b - diff * (1 - gamma), a + diff * gamma)


def _time_varying(matrix: np.ndarray, levels: np.ndarray, min_support: int | None) -> np.ndarray:
    """Per-step quantiles ``[len(levels), length]`` with the core's support rule."""
    supported = _supported_length(matrix, min_support)
    head = np.sort(matrix[:, :supported], axis=0)  # NaN (ended rollouts) sort last
    values = _linear_quantiles(head, np.sum(~np.isnan(head), axis=0), levels)
    return np.stack([_carried(row, supported, matrix.shape[1]) for row in values])


def _cp_band(curves: list[np.ndarray], length: int, deltas: Sequence[float], s: ThresholdSettings,
             shape: list[np.ndarray] | None) -> tuple[np.ndarray, list[dict[str, float | int]]]:
    """``mu + k(delta) s`` ``[len(deltas), length]`` (reference band rule: as long as ``mu``): the core's band
    statistics once, ``k`` per delta."""
    if s.band_rule == "reference":
        band = AuthorsBand.of(curves, shape)
        kept = [band.kept(delta) for delta in deltas]
        per_kept = {chosen: band.statistics(chosen, s.band_sign) for chosen in dict.fromkeys(kept)}
        every = [per_kept[chosen] for chosen in kept]
    else:
        every = [band_statistics(curves, length, s, shape)] * len(deltas)
    ks = [_quantile(stats.band_scores, delta, s.conformal) for stats, delta in zip(every, deltas)]
    return (np.stack([stats.values(k) for stats, k in zip(every, ks)]),
            [{"k": float(k), "m1": stats.m1, "m2": stats.m2, "s_floor": stats.floor} for stats, k in zip(every, ks)])


def _cp_scaled(curves: list[np.ndarray], length: int, deltas: Sequence[float], s: ThresholdSettings,
               shape: list[np.ndarray] | None) -> tuple[np.ndarray, list[dict[str, float | int]]]:
    """``k(delta) q_delta(t)`` ``[len(deltas), length]``: every level's ``q`` at once, then the core's rules."""
    set1, set2 = _shape_and_conformal(curves, s, shape)
    padded = _padded(set1, length)
    quantiles = _time_varying(padded, np.array([1.0 - d for d in deltas]), s.min_support)
    supported = _supported_length(padded, s.min_support)
    rows, params = [], []
    for delta, q in zip(deltas, quantiles):
        scale, floor = _floored(q, supported, s, q)
        stats = BandStatistics(np.zeros(length), scale, np.array([np.max(c / scale[: c.shape[0]]) for c in set2]),
                               len(set1), len(set2), floor)
        k = _quantile(stats.band_scores, delta, s.conformal)
        rows.append(stats.values(k))
        params.append({"k": float(k), "m1": stats.m1, "m2": stats.m2, "q_floor": stats.floor})
    return np.stack(rows), params


def fit_threshold_grid(
    curves: Sequence[np.ndarray], kinds: Sequence[str], deltas: Sequence[float], settings: ThresholdSettings,
    shape_curves: Sequence[np.ndarray] | None = None,
) -> dict[str, list[Threshold]]:
    """Per kind, ``[fit_threshold(curves, replace(settings, kind=kind, delta=d), shape_curves) for d in deltas]``."""
    checked = _validated(curves)
    shape = None if shape_curves is None else _validated(shape_curves)
    length = max(curve.shape[0] for curve in checked + (shape or []))
    out: dict[str, list[Threshold]] = {}
    for kind in kinds:
        params: list[dict[str, float | int]] = [{} for _ in deltas]
        if kind == "cp_constant":
            maxima = np.array([curve.max() for curve in checked])
            values = np.stack([np.full(length, _quantile(maxima, d, settings.conformal)) for d in deltas])
        elif kind == "time_varying":
            levels = np.array([1.0 - d for d in deltas])
            values = _time_varying(_padded(checked, length), levels, settings.min_support)
        elif kind == "cp_band":
            values, params = _cp_band(checked, length, deltas, settings, shape)
        elif kind == "cp_scaled":
            values, params = _cp_scaled(checked, length, deltas, settings, shape)
        else:
            raise ValueError(f"threshold kind {kind!r} is not swept; expected one of {GRID_KINDS}")
        out[kind] = [Threshold(kind, float(d), row, settings.extension, {"m": len(checked), **extra})
                     for d, row, extra in zip(deltas, values, params)]
    return out
