"""Thresholds, Sec. 4.3 and App. A.3, including the conformal guarantee checked empirically."""

from __future__ import annotations

import logging
import math
from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.thresholds import (
    Threshold,
    ThresholdError,
    ThresholdSettings,
    conformal_quantile,
    fit_threshold,
)


def test_conformal_quantile_rank() -> None:
    scores = np.arange(10, 0, -1, dtype=float)  # 1..10, unsorted
    assert conformal_quantile(scores, 0.1) == 10.0  # ceil(11 * 0.9) = 10
    assert conformal_quantile(scores, 0.2) == 9.0  # ceil(11 * 0.8) = 9
    assert conformal_quantile(scores, 0.5) == 6.0  # ceil(5.5) = 6
    assert conformal_quantile(np.arange(19.0), 0.05) == 18.0  # (M+1)(1-delta) = 19 exactly


def test_conformal_quantile_too_few_scores_is_infinite(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        assert conformal_quantile(np.arange(10.0), 0.05) == math.inf
    assert "threshold is +inf" in caplog.text


def test_cp_constant_uses_rollout_maxima() -> None:
    curves = [np.array([0.0, i, 0.5]) for i in range(1, 11)]
    threshold = fit_threshold(curves, ThresholdSettings(kind="cp_constant", delta=0.2))
    assert np.array_equal(threshold.values, np.full(3, 9.0))
    plain = fit_threshold(curves, ThresholdSettings(kind="cp_constant", delta=0.2, conformal=False))
    # linear 0.8 quantile of the maxima 1..10: index (10 - 1) * 0.8 = 7.2 -> 8 + 0.2 * (9 - 8) = 8.2
    assert plain.values[0] == pytest.approx(8.2)


def test_time_varying_is_a_per_step_quantile() -> None:
    curves = [np.full(3, float(v)) for v in range(1, 6)]
    threshold = fit_threshold(curves, ThresholdSettings(kind="time_varying", delta=0.2))
    assert np.allclose(threshold.values, 4.2)


def test_support_rule_carries_the_last_well_supported_value() -> None:
    rng = np.random.default_rng(0)
    curves = [rng.random(10) for _ in range(5)] + [np.full(20, 100.0)]
    threshold = fit_threshold(curves, ThresholdSettings(kind="time_varying", delta=0.1, min_support=5))
    assert threshold.values.shape == (20,)
    assert np.all(threshold.values[10:] == threshold.values[9])
    unsupported = fit_threshold(curves, ThresholdSettings(kind="time_varying", delta=0.1, min_support=1))
    assert np.all(unsupported.values[10:] == 100.0)


def test_extension_rules() -> None:
    values = np.array([1.0, 3.0, 2.0])
    for extension, tail in (("last", 2.0), ("mean", 2.0), ("max", 3.0)):
        threshold = Threshold("time_varying", 0.1, values, extension)
        assert threshold.at(1) == 3.0 and threshold.at(10) == tail
        assert np.array_equal(threshold.over(5), [1.0, 3.0, 2.0, tail, tail])
    assert Threshold("time_varying", 0.1, np.array([1.0, 2.0, 6.0]), "mean").at(7) == 3.0


def test_threshold_dict_round_trip() -> None:
    threshold = Threshold("cp_band", 0.05, np.array([0.1, math.inf, 1 / 3]), "max", {"k": 1.5})
    again = Threshold.from_dict(threshold.to_dict())
    assert np.array_equal(again.values, threshold.values)
    assert (again.kind, again.delta, again.extension, again.params) == ("cp_band", 0.05, "max", {"k": 1.5})


def test_errors() -> None:
    with pytest.raises(ThresholdError, match="no calibration curves"):
        fit_threshold([])
    with pytest.raises(ThresholdError, match="at least 2"):
        fit_threshold([np.ones(4)], ThresholdSettings(kind="cp_band"))
    with pytest.raises(ThresholdError, match="kind"):
        ThresholdSettings(kind="best")
    with pytest.raises(ThresholdError, match="NaN"):
        fit_threshold([np.array([1.0, np.nan])])


#: A seeded split, by hand: ``np.random.default_rng(1).permutation(4)`` is ``[0, 1, 2, 3]``, so with
#: ``band_split`` 0.5 the curves 0, 1 form ``I1`` and the curves 2, 3 form ``I2``.
SPLIT_SEED = 1


def test_band_by_hand_with_the_floor_and_independent_of_i2_for_its_shape() -> None:
    i1 = [np.array([1.0, 2.0, 2.0]), np.array([3.0, 6.0, 2.0])]
    # mu = [2, 4, 2]; s (population std) = [1, 2, 0], mean 1, floor 0.1 * 1 = 0.1 -> scale = [1, 2, 0.1]
    c2, c3 = np.array([2.5, 5.0, 2.1]), np.array([4.0, 4.0, 1.0])
    # R_2 = max(0.5 / 1, 1 / 2, 0.1 / 0.1) = 1;  R_3 = max(2 / 1, 0 / 2, -1 / 0.1) = 2
    settings = ThresholdSettings(kind="cp_band", delta=0.4, seed=SPLIT_SEED)
    fitted = fit_threshold([*i1, c2, c3], settings)
    # M2 = 2, rank ceil(3 * 0.6) = 2: k = 2 -> gamma = mu + 2 scale = [4, 8, 2.2]
    assert (fitted.params["m1"], fitted.params["m2"]) == (2, 2)
    assert fitted.params["s_floor"] == pytest.approx(0.1)
    assert fitted.params["k"] == pytest.approx(2.0)
    np.testing.assert_allclose(fitted.values, [4.0, 8.0, 2.2])
    # delta 0.7: rank ceil(3 * 0.3) = 1: k = 1 -> [3, 6, 2.1]
    looser = fit_threshold([*i1, c2, c3], replace(settings, delta=0.7))
    assert looser.params["k"] == pytest.approx(1.0)
    np.testing.assert_allclose(looser.values, [3.0, 6.0, 2.1])
    # I2 sets only k: c3 = [6, 4, 1] gives R_3 = 4, k = 4 and gamma = [2 + 4, 4 + 8, 2 + 0.4]; mu and s stay
    changed = fit_threshold([*i1, c2, np.array([6.0, 4.0, 1.0])], settings)
    assert changed.params["k"] == pytest.approx(4.0)
    np.testing.assert_allclose(changed.values, [6.0, 12.0, 2.4])


def _score_curves(rng: np.random.Generator, count: int) -> list[np.ndarray]:
    """i.i.d. windowed score curves with a time trend, heteroscedastic noise and varying length."""
    curves = []
    for _ in range(count):
        length = int(rng.integers(15, 26))
        t = np.arange(length)
        scores = (1.0 + 0.05 * t) * rng.lognormal(0.0, 0.3 + 0.02 * t)
        curves.append(np.convolve(scores, np.ones(3))[:length])
    return curves


def _false_alarm_rate(threshold: Threshold, curves: list[np.ndarray]) -> float:
    return float(np.mean([np.any(c > threshold.over(c.shape[0])) for c in curves]))


@pytest.mark.parametrize("kind", ["cp_constant", "cp_band"])
def test_conformal_false_alarm_rate_is_bounded(kind: str) -> None:
    rng = np.random.default_rng(11)
    delta, m, trials, fresh = 0.2, 30, 150, 200
    settings = ThresholdSettings(kind=kind, delta=delta)
    rates = np.array([
        _false_alarm_rate(fit_threshold(_score_curves(rng, m), settings), _score_curves(rng, fresh))
        for _ in range(trials)
    ])
    standard_error = rates.std(ddof=1) / math.sqrt(trials)
    assert rates.mean() <= delta + 3 * standard_error
    if kind == "cp_constant":  # the conformal quantile is also tight: coverage <= 1 - delta + 1/(M+1)
        assert rates.mean() >= delta - 1 / (m + 1) - 3 * standard_error


def test_lower_band_sign_of_the_reference_code_breaks_the_bound() -> None:
    rng = np.random.default_rng(12)
    settings = ThresholdSettings(kind="cp_band", delta=0.2, band_sign="lower")
    rates = [
        _false_alarm_rate(fit_threshold(_score_curves(rng, 30), settings), _score_curves(rng, 200)) for _ in range(40)
    ]
    assert np.mean(rates) > 0.5


def test_gaussian_threshold_by_hand() -> None:
    i1 = [np.array([1.0, 1.0]), np.array([3.0, 3.0])]  # mu = [2, 2]
    i2 = [np.array([3.0, -2.0]), np.array([9.0, 6.0])]
    # sigma is the RMS deviation of I2 from mu (not I2's own spread):
    # t = 0: deviations 1, 7 -> sqrt((1 + 49) / 2) = 5;  t = 1: deviations -4, 4 -> sqrt((16 + 16) / 2) = 4
    for delta, z in ((0.1, 1.2815515655446004), (0.05, 1.6448536269514722)):  # z = Phi^-1(1 - delta), from tables
        gaussian = fit_threshold([*i1, *i2], ThresholdSettings(kind="gaussian", delta=delta, seed=SPLIT_SEED))
        assert gaussian.params["z"] == pytest.approx(z)
        np.testing.assert_allclose(gaussian.values, [2.0 + 5.0 * z, 2.0 + 4.0 * z])
