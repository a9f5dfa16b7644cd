"""The equalisers of a joint combination (core/equalisation.py): the quantile and tail maps by hand, their inverse,
monotonicity and continuity (hypothesis), and the refusals."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.equalisation import (TIE_RESOLUTION, Equaliser, check_equalisation, fit_equaliser,
                                         quantile_equaliser, tail_equaliser)
from fiper_ros.core.thresholds import ThresholdError


def test_quantile_map_by_hand() -> None:
    """Maxima (1, 2, 3, 5): the 0.5 quantile is 2.5 (linear interpolation), so T(z) = z / 2.5 everywhere."""
    equaliser = quantile_equaliser(np.array([5.0, 1.0, 3.0, 2.0]), 0.5)
    assert equaliser.knots.tolist() == [0.0, 2.5] and equaliser.levels.tolist() == [0.0, 1.0]
    assert equaliser(np.array([-1.0, 0.0, 1.25, 2.5, 5.0])).tolist() == [-0.4, 0.0, 0.5, 1.0, 2.0]
    assert equaliser.inverse(2.0) == 5.0 and equaliser.inverse(0.5) == 1.25 and equaliser.inverse(-0.4) == -1.0


def test_tail_map_by_hand() -> None:
    """Maxima (1, 2, 2, 4), n = 4: S(1) = 4/5, S(2) = 2/5 (the tie takes its larger rank 3), S(4) = 1/5, so the levels
    -log S are log(5/4), log(5/2), log 5; the median knot (the first of rank >= 2.5) is 2, and the ends continue with
    the secant slope (log 5 - log 5/2) / (4 - 2) = log(2) / 2."""
    equaliser = tail_equaliser(np.array([2.0, 4.0, 1.0, 2.0]))
    assert equaliser.knots.tolist() == [1.0, 2.0, 4.0]
    np.testing.assert_allclose(equaliser.levels, [math.log(5 / 4), math.log(5 / 2), math.log(5)], rtol=1e-15)
    assert equaliser.below == equaliser.above == pytest.approx(math.log(2) / 2, rel=1e-15)
    z = np.array([0.0, 1.5, 3.0, 6.0, np.nan])
    expected = [math.log(5 / 4) - math.log(2) / 2,  # one step below the first knot at the end slope
                (math.log(5 / 4) + math.log(5 / 2)) / 2,  # half-way between the first two knots
                (math.log(5 / 2) + math.log(5)) / 2,
                math.log(5) + math.log(2)]  # two steps above the last knot
    np.testing.assert_allclose(equaliser(z)[:4], expected, rtol=1e-14)
    assert math.isnan(equaliser(z)[4])
    assert equaliser.inverse(math.log(5) + math.log(2)) == pytest.approx(6.0, rel=1e-14)
    assert equaliser.inverse(math.inf) == math.inf


def test_the_tail_map_is_the_smallest_p_value_at_the_maxima() -> None:
    """At each fit maximum x_(i) (distinct), exp(-T) is the plotting position 1 - i / (n + 1)."""
    maxima = np.array([0.3, 1.7, 0.9, 2.2, 5.0])
    equaliser = tail_equaliser(maxima)
    np.testing.assert_allclose(np.exp(-equaliser(np.sort(maxima))), 1.0 - np.arange(1, 6) / 6.0, rtol=1e-14)


@settings(max_examples=80, deadline=None)
@given(st.lists(st.floats(-50.0, 50.0, allow_nan=False), min_size=2, max_size=40), st.sampled_from(["quantile",
                                                                                                       "tail"]))
def test_every_equaliser_is_continuous_strictly_increasing_and_inverted(values: list[float], kind: str) -> None:
    maxima = np.array(values)
    if kind == "quantile":
        maxima = np.abs(maxima) + 0.5  # a positive quantile
    if np.unique(maxima).shape[0] < 2:
        return
    if kind == "tail" and np.ptp(maxima) <= TIE_RESOLUTION * max(1.0, float(np.max(np.abs(maxima)))):
        with pytest.raises(ThresholdError, match="at least 2 distinct maxima"):
            fit_equaliser(kind, maxima, 0.9)
        return
    equaliser = fit_equaliser(kind, maxima, 0.9)
    span = float(np.ptp(maxima)) + 1.0
    z = np.linspace(maxima.min() - 3 * span, maxima.max() + 3 * span, 2001)
    mapped = equaliser(z)
    assert np.all(np.isfinite(mapped)) and np.all(np.diff(mapped) > 0)
    steepest = max(float(np.max(np.diff(equaliser.levels) / np.diff(equaliser.knots))), equaliser.below,
                   equaliser.above)
    assert np.max(np.diff(mapped) / np.diff(z)) <= steepest * (1 + 1e-9)  # no jump anywhere: continuous
    for k in mapped[::97]:
        assert equaliser(np.array([equaliser.inverse(float(k))]))[0] == pytest.approx(k, rel=1e-9, abs=1e-9)


def test_maxima_a_subnormal_gap_apart_are_one_knot() -> None:
    # hypothesis found these: the gap of 2e-311 made the slope between two knots overflow (a non-finite map),
    # and [0, 2e-313] an infinite end slope (a refusal about slopes instead of the missing second value)
    equaliser = tail_equaliser(np.array([1.0, 2.2250738585e-313, -1.0, -2.225073858507e-311]))
    assert equaliser.knots.tolist() == [-1.0, 2.2250738585e-313, 1.0]
    assert equaliser.levels.tolist() == pytest.approx([np.log(5 / 4), np.log(5 / 2), np.log(5)])
    mapped = equaliser(np.linspace(-10.0, 10.0, 2001))
    assert np.all(np.isfinite(mapped)) and np.all(np.diff(mapped) > 0)
    with pytest.raises(ThresholdError, match=r"^tail equalisation needs at least 2 distinct maxima in the fit part, "
                                             r"got 1 \(of 2\); maxima 1e-09 apart or less count as one$"):
        tail_equaliser(np.array([0.0, 2.2250738585e-313]))


def test_round_trip_through_plain_data() -> None:
    equaliser = tail_equaliser(np.array([0.5, 1.0, 4.0]))
    again = Equaliser.from_dict(equaliser.to_dict())
    assert again.to_dict() == equaliser.to_dict() and again.kind == "tail"


def test_refusals_name_what_is_wrong() -> None:
    with pytest.raises(ThresholdError, match=r"^unknown equalisation 'median'; expected one of none, quantile, tail$"):
        check_equalisation("median", 0.9)
    with pytest.raises(ThresholdError, match=r"^the equalisation level must be in \(0, 1\), got 1\.0$"):
        check_equalisation("quantile", 1.0)
    with pytest.raises(ThresholdError, match=r"^quantile equalisation needs a positive 0\.9 quantile of the fit "
                                             r"part's maxima, got -1 \(equalise tail instead\)$"):
        quantile_equaliser(np.array([-1.0, -2.0, -1.0]))
    with pytest.raises(ThresholdError, match=r"^tail equalisation needs at least 2 distinct maxima in the fit part, "
                                             r"got 1 \(of 3\)$"):
        tail_equaliser(np.ones(3))
    with pytest.raises(ThresholdError, match=r"^an equaliser's maxima must be finite$"):
        tail_equaliser(np.array([1.0, np.inf]))
    with pytest.raises(ThresholdError, match=r"^equalisation 'none' has no equaliser$"):
        fit_equaliser("none", np.ones(3))
    with pytest.raises(ThresholdError, match=r"knots and levels must be finite and strictly increasing"):
        Equaliser("tail", np.array([0.0, 0.0]), np.array([0.0, 1.0]), 1.0, 1.0)
    with pytest.raises(ThresholdError, match=r"^equaliser entry lacks 'above'$"):
        Equaliser.from_dict({"kind": "tail", "knots": [0, 1], "levels": [0, 1], "below": 1})
