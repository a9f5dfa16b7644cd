"""Thresholds, Sec. 4.3 and App. A.3, including the conformal guarantee checked empirically."""

from __future__ import annotations

import logging
import math

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
    assert plain.values[0] == pytest.approx(np.quantile(np.arange(1.0, 11.0), 0.8))


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


def test_band_matches_a_direct_computation_and_ignores_i2_for_its_shape() -> None:
    rng = np.random.default_rng(3)
    curves = [np.cumsum(rng.random(12)) for _ in range(20)]
    settings = ThresholdSettings(kind="cp_band", delta=0.2, seed=5)
    order = np.random.default_rng(5).permutation(20)
    first, second = np.stack([curves[i] for i in order[:10]]), [curves[i] for i in order[10:]]
    mu, spread = first.mean(axis=0), first.std(axis=0)
    scale = np.maximum(spread, 0.1 * spread.mean())
    k = conformal_quantile([np.max((c - mu) / scale) for c in second], 0.2)
    fitted = fit_threshold(curves, settings)
    assert fitted.params["k"] == pytest.approx(k)
    assert np.allclose(fitted.values, mu + k * scale)
    changed = list(curves)
    for i in order[10:]:
        changed[i] = curves[i] * 1.3
    refitted = fit_threshold(changed, settings)
    assert refitted.params["k"] > k
    assert np.allclose(refitted.values, mu + refitted.params["k"] * scale)


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


def test_gaussian_threshold_lies_above_the_mean() -> None:
    rng = np.random.default_rng(13)
    curves = _score_curves(rng, 40)
    gaussian = fit_threshold(curves, ThresholdSettings(kind="gaussian", delta=0.1))
    mean = np.mean([c[:15] for c in curves], axis=0)
    assert np.all(gaussian.values[:15] > mean)
    assert gaussian.params["z"] == pytest.approx(1.2815515655446004)
