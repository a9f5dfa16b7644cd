"""Thresholds, Sec. 4.3 and App. A.3, including the conformal guarantee checked empirically."""

from __future__ import annotations

import logging
import math
import re
from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.thresholds import (
    AuthorsBand,
    Threshold,
    ThresholdError,
    ThresholdSettings,
    conformal_quantile,
    fit_threshold,
    minimum_conformal_set,
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


def test_gaussian_honours_min_support_in_both_halves() -> None:
    # I1 = curves 0, 1 (SPLIT_SEED); min_support 1 lets a step count with one rollout of a half (default: 2).
    i1 = [np.array([1.0, 1.0, 1.0]), np.array([3.0])]  # mu = [2, 1, 1]
    i2 = [np.array([3.0, 2.0, 4.0]), np.array([9.0])]  # deviations: t = 0: 1, 7 -> 5; t = 1: 1; t = 2: 3
    settings = ThresholdSettings(kind="gaussian", delta=0.1, seed=SPLIT_SEED, min_support=1)
    fitted = fit_threshold([*i1, *i2], settings)
    z = 1.2815515655446004
    np.testing.assert_allclose(fitted.values, [2.0 + 5.0 * z, 1.0 + z, 1.0 + 3.0 * z])
    assert fitted.params == {"m": 4, "z": pytest.approx(z), "m1": 2, "m2": 2}
    assert (fitted.kind, fitted.delta) == ("gaussian", 0.1)


def test_cp_band_honours_min_support_for_mu_the_spread_and_the_floor() -> None:
    i1 = [np.array([1.0, 2.0, 4.0]), np.array([3.0])]
    # min_support 1: mu = [2, 2, 4]; s = [1, 0, 0], floor 0.1 * mean(s) = 1/30 -> scale = [1, 1/30, 1/30]
    i2 = [np.array([2.0, 2.0, 4.0]), np.array([3.0])]  # R = 0 and (3 - 2) / 1 = 1
    settings = ThresholdSettings(kind="cp_band", delta=0.4, seed=SPLIT_SEED, min_support=1)
    fitted = fit_threshold([*i1, *i2], settings)  # rank ceil(3 * 0.6) = 2 of M2 = 2: k = 1
    assert fitted.params["k"] == pytest.approx(1.0)
    assert fitted.params["s_floor"] == pytest.approx(1 / 30)
    np.testing.assert_allclose(fitted.values, [3.0, 2.0 + 1 / 30, 4.0 + 1 / 30])


def test_cp_band_floor_when_every_i1_curve_is_the_same() -> None:
    # s = 0 everywhere, so 0.1 * mean(s) = 0: the floor falls back to 1e-12 max(1, max |mu|) = 1.5e-12
    same = np.array([1.0, 1.5])
    fitted = fit_threshold([same, same, same, same + np.array([0.0, 3e-12])],
                           ThresholdSettings(kind="cp_band", delta=0.4, seed=SPLIT_SEED))
    assert fitted.params["s_floor"] == pytest.approx(1.5e-12, rel=1e-9)
    assert fitted.params["k"] == pytest.approx(2.0, rel=1e-3)  # R = 0 and 3e-12 / 1.5e-12
    assert np.all(np.isfinite(fitted.values))


@pytest.mark.parametrize(("m", "band_split", "m1"), [(2, 0.5, 1), (2, 0.9, 1), (4, 0.9, 3), (5, 0.1, 1)])
def test_split_sizes_keep_both_halves_non_empty(m: int, band_split: float, m1: int) -> None:
    # m1 = round(band_split * m), at least 1 and at most m - 1 (round(0.5) = 0, round(3.6) = 4)
    curves = [np.array([float(i), 1.0]) for i in range(m)]
    for kind in ("cp_band", "gaussian"):
        fitted = fit_threshold(curves, ThresholdSettings(kind=kind, delta=0.5, band_split=band_split))
        assert (fitted.params["m1"], fitted.params["m2"]) == (m1, m - m1), kind


@pytest.mark.parametrize(("m", "expected"), [(26, [1.0, 3.0]), (30, [1.0, 1.0])])
def test_default_min_support_is_a_fifth_of_m_but_at_least_five(m: int, expected: list[float]) -> None:
    # five rollouts reach step 1: enough for M = 26 (need max(5, 26 // 5) = 5), not for M = 30 (need 6)
    curves = [np.array([1.0])] * (m - 5) + [np.array([1.0, 3.0])] * 5
    assert fit_threshold(curves, ThresholdSettings(kind="time_varying", delta=0.1)).values.tolist() == expected


def test_single_step_curves_and_a_single_score_are_enough() -> None:
    fitted = fit_threshold([np.array([2.0]), np.array([4.0])], ThresholdSettings(kind="cp_constant", delta=0.5))
    assert fitted.values.tolist() == [4.0]  # rank ceil(3 * 0.5) = 2 of the maxima [2, 4]
    assert conformal_quantile([3.0], 0.5) == 3.0  # rank ceil(2 * 0.5) = 1


def test_conformal_warning_names_m_and_delta(caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING):
        conformal_quantile([1.0, 2.0, 3.0], 0.1)
    assert [r.getMessage() for r in caplog.records] == [
        "conformal level ceil((M+1)(1-delta))/M > 1 for M=3, delta=0.1: threshold is +inf"]


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"delta": 0.0}, "delta must be in (0, 1), got 0.0"),
        ({"delta": 1.0}, "delta must be in (0, 1), got 1.0"),
        ({"extension": "first"}, "unknown extension 'first'; expected one of ('last', 'mean', 'max')"),
        ({"band_sign": "both"}, "unknown band_sign 'both'; expected one of ('upper', 'lower')"),
        ({"band_split": 0.0}, "band_split must be in (0, 1), got 0.0"),
        ({"band_split": 1.0}, "band_split must be in (0, 1), got 1.0"),
        ({"min_support": 0}, "min_support must be >= 1, got 0"),
        ({"std_floor": -0.1}, "std_floor must be >= 0, got -0.1"),
    ],
)
def test_settings_rejections_name_the_setting(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ThresholdError, match=f"^{re.escape(message)}$"):
        ThresholdSettings(**changes)  # type: ignore[arg-type]


def test_a_zero_std_floor_is_allowed() -> None:
    assert ThresholdSettings(std_floor=0.0).std_floor == 0.0


def test_threshold_values_are_a_read_only_float64_vector_without_nan() -> None:
    threshold = Threshold("time_varying", 0.1, [1, 2])  # type: ignore[arg-type]
    assert isinstance(threshold.values, np.ndarray) and threshold.values.dtype == np.float64
    with pytest.raises(ValueError, match="read-only"):
        threshold.values[0] = 5.0
    for values, message in (([[1.0, 2.0]], "threshold values must be a non-empty 1-D array, got shape (1, 2)"),
                            ([1.0, math.nan], "threshold values contain NaN")):
        with pytest.raises(ThresholdError, match=f"^{re.escape(message)}$"):
            Threshold("time_varying", 0.1, np.array(values))
    with pytest.raises(ThresholdError, match=r"^unknown extension 'first'; expected one of "):
        Threshold("time_varying", 0.1, np.ones(2), "first")
    with pytest.raises(IndexError, match=r"^policy step must be >= 0, got -1$"):
        threshold.at(-1)


def test_threshold_entry_defaults_and_missing_keys() -> None:
    plain = Threshold.from_dict({"kind": "cp_constant", "delta": 0.1, "values": [2.0]})
    assert (plain.extension, plain.params, plain.at(5)) == ("last", {}, 2.0)
    with pytest.raises(ThresholdError, match=r"^threshold entry lacks 'values'$"):
        Threshold.from_dict({"kind": "cp_constant", "delta": 0.1})


def test_calibration_curve_rejections_name_the_curve() -> None:
    message = "no calibration curves: thresholds need successful calibration rollouts"
    with pytest.raises(ThresholdError, match=f"^{re.escape(message)}$"):
        fit_threshold([])
    message = "calibration curve 1 must be a non-empty 1-D array, got shape (2, 2)"
    with pytest.raises(ThresholdError, match=f"^{re.escape(message)}$"):
        fit_threshold([np.ones(3), np.ones((2, 2))])
    with pytest.raises(ThresholdError, match=r"^conformal quantile of no scores$"):
        conformal_quantile([], 0.1)


# ---- issue #27, second round: survivors of `make mutants FILES=core/thresholds.py` in the code of #19 ----------------
@pytest.mark.parametrize(("delta", "m"), [(0.05, 19), (0.1, 9), (0.2, 4), (0.25, 3), (0.4, 2), (0.5, 1), (0.9, 1),
                                          (0.01, 99), (1 / 3, 2), (0.3, 3)])
def test_minimum_conformal_set_by_hand(delta: float, m: int) -> None:
    # the smallest M with ceil((M + 1)(1 - delta)) <= M; M - 1 scores give +inf
    assert minimum_conformal_set(delta) == m
    assert math.isfinite(conformal_quantile(np.arange(float(m)), delta))
    if m > 1:
        assert conformal_quantile(np.arange(float(m - 1)), delta) == math.inf


@given(st.floats(min_value=1e-3, max_value=1.0 - 1e-9, exclude_max=True))
def test_minimum_conformal_set_is_where_the_conformal_quantile_turns_finite(delta: float) -> None:
    m = minimum_conformal_set(delta)
    assert m >= 1 and math.isfinite(conformal_quantile(np.zeros(m), delta))
    assert m == 1 or conformal_quantile(np.zeros(m - 1), delta) == math.inf


@pytest.mark.parametrize("delta", [0.0, 1.0, -0.1, 1.5])
def test_minimum_conformal_set_refuses_a_delta_outside_0_1(delta: float) -> None:
    with pytest.raises(ThresholdError, match=rf"^delta must be in \(0, 1\), got {delta}$"):
        minimum_conformal_set(delta)


def test_gaussian_takes_mu_from_the_given_shape_curves_and_sigma_from_the_curves() -> None:
    shape = [np.array([1.0, 1.0]), np.array([3.0, 3.0])]  # mu = [2, 2]
    curves = [np.array([3.0, -2.0]), np.array([9.0, 6.0])]  # RMS deviations from mu: 5, 4
    fitted = fit_threshold(curves, ThresholdSettings(kind="gaussian", delta=0.1), shape_curves=shape)
    z = 1.2815515655446004
    np.testing.assert_allclose(fitted.values, [2.0 + 5.0 * z, 2.0 + 4.0 * z])
    assert (fitted.params["m1"], fitted.params["m2"]) == (2, 2)


def test_cp_band_floor_is_the_mean_spread_over_the_supported_steps_only() -> None:
    # min_support 2: steps 0 and 1 are supported, step 2 (one rollout) carries step 1's std: s = [1, 2, 2].
    # The floor is 0.1 x mean(1, 2) = 0.15, not 0.1 x mean(1, 2, 2).
    shape = [np.array([0.0, 0.0, 9.0]), np.array([2.0, 4.0])]
    fitted = fit_threshold([np.array([1.0, 2.0, 2.0])], ThresholdSettings(kind="cp_band", delta=0.5, min_support=2),
                           shape_curves=shape)
    assert fitted.params["s_floor"] == pytest.approx(0.15)
    np.testing.assert_allclose(fitted.values, [1.0, 2.0, 2.0])  # mu = [1, 2, 2], k = max((c - mu) / s) = 0


def test_cp_scaled_floor_falls_back_to_a_tiny_positive_scale_when_every_quantile_is_0() -> None:
    shape = [np.zeros(2), np.zeros(2)]
    fitted = fit_threshold([np.array([0.0, 2e-12])], ThresholdSettings(kind="cp_scaled", delta=0.5, min_support=1),
                           shape_curves=shape)
    assert fitted.params["q_floor"] == pytest.approx(1e-12, rel=1e-12)
    assert fitted.params["k"] == pytest.approx(2.0)  # max(0 / 1e-12, 2e-12 / 1e-12)
    np.testing.assert_allclose(fitted.values, [2e-12, 2e-12])


@pytest.mark.parametrize(("kind", "floor_key"), [("cp_band", "s_floor"), ("cp_scaled", "q_floor")])
def test_the_conformal_factor_is_the_conformal_rank_not_the_plain_quantile(kind: str, floor_key: str) -> None:
    # Shape curves of ones: mu = 1, s = 0 -> floor 1e-12 (cp_band); q = 1, scale 1 (cp_scaled). Four I2 curves.
    shape = [np.ones(1), np.ones(1)]
    curves = [np.array([v]) for v in (0.0, 1.0, 2.0, 3.0)]
    settings = ThresholdSettings(kind=kind, delta=0.4, min_support=1)
    conformal = fit_threshold(curves, settings, shape_curves=shape)
    plain = fit_threshold(curves, replace(settings, conformal=False), shape_curves=shape)
    if kind == "cp_scaled":  # scores c / 1: rank ceil(5 x 0.6) = 3 of [0, 1, 2, 3] -> 2; np.quantile(0.6) -> 1.8
        assert (conformal.params["k"], plain.params["k"]) == (2.0, pytest.approx(1.8))
        np.testing.assert_allclose(conformal.values, [2.0])
    else:  # scores (c - 1) / 1e-12: the same ranks
        assert conformal.params["k"] == pytest.approx(1e12) and plain.params["k"] == pytest.approx(0.8e12)
    assert set(conformal.params) == {"m", "k", "m1", "m2", floor_key}
    assert (conformal.params["m"], conformal.params["m1"], conformal.params["m2"]) == (4, 2, 4)


# The authors' CP band (band_rule="reference"): hand cases from their formulas, then a step-by-step oracle.
AUTHORS = ThresholdSettings(kind="cp_band", band_rule="reference", band_sign="lower", conformal=False,
                            extension="mean", min_support=1)


def test_authors_split_takes_the_first_longest_curve_and_the_first_half_of_the_others_in_order() -> None:
    c0, c1, c2, c3, c4 = (np.array([3.0, 4.0]), np.array([1.0, 2.0, 3.0]), np.array([2.0]),
                          np.array([2.0, 5.0, 2.5]), np.array([0.0, 3.0]))
    band = AuthorsBand.of([c0, c1, c2, c3, c4])
    # c1 and c3 are both longest: the first, c1, leads I1; of [c0, c2, c3, c4] the first floor(4 / 2) join it
    assert [id(c) for c in band.set1] == [id(c1), id(c0), id(c2)]
    assert [id(c) for c in band.set2] == [id(c3), id(c4)]
    np.testing.assert_array_equal(band.mu, [2.0, 3.0, 3.0])  # (1 + 3 + 2) / 3, (2 + 4) / 2, 3
    np.testing.assert_array_equal(band.deviations, [1.0, 1.0, 0.0])
    # in another order c3 is the first longest one, and the split changes with it
    assert [id(c) for c in AuthorsBand.of([c3, c0, c1, c2, c4]).set1] == [id(c3), id(c0), id(c1)]


def test_authors_band_by_hand_with_the_1_over_t_max_fill_in() -> None:
    curves = [np.array([3.0, 4.0]), np.array([1.0, 2.0, 3.0]), np.array([2.0]), np.array([2.0, 5.0, 2.5]),
              np.array([0.0, 3.0])]
    # delta 0.2: N1 = 3, (3 + 1) 0.8 = 3.2 > 3 keeps every I1 curve. s(t) = max |eta - mu| over them:
    # t = 0: max(1, 1, 0) = 1; t = 1: max(1, 1) = 1; t = 2: |3 - 3| = 0 < 1e-7 -> 1 / T_1 = 1 / 3.
    # Band scores (mu - eta) / s: c3 max(0, -2, 0.5 * 3) = 1.5; c4 max(2, 0) = 2 -> k = np.quantile(0.8) = 1.9
    fitted = fit_threshold(curves, replace(AUTHORS, delta=0.2))
    assert (fitted.params["m1"], fitted.params["m2"]) == (3, 2)
    assert fitted.params["s_floor"] == pytest.approx(1 / 3)
    assert fitted.params["k"] == pytest.approx(1.9)
    np.testing.assert_allclose(fitted.values, [2.0 + 1.9, 3.0 + 1.9, 3.0 + 1.9 / 3])
    # the upper sign (eta - mu) / s: c3 max(0, 2, -1.5) = 2, c4 max(-2, 0) = 0 -> k = 1.6
    assert fit_threshold(curves, replace(AUTHORS, delta=0.2, band_sign="upper")).params["k"] == pytest.approx(1.6)


def test_authors_filter_both_branches_and_the_1_over_t_fill_in() -> None:
    longest, a, b = np.array([6.0, 0.0, 0.0, 0.0]), np.array([0.0, 2.0]), np.array([0.0, 4.0, 3.0])
    x, y = np.array([1.0, 1.0, 1.0, 1.0]), np.array([3.0, 3.0])
    curves = [longest, a, b, x, y]  # I1 = [longest, a, b], I2 = [x, y]
    band = AuthorsBand.of(curves)
    np.testing.assert_array_equal(band.mu, [2.0, 2.0, 1.5, 0.0])
    np.testing.assert_array_equal(band.deviations, [4.0, 2.0, 2.0])  # |6 - 2|; |0 - 2|; |0 - 2| = |4 - 2|
    # delta 0.2: (3 + 1) 0.8 = 3.2 > 3: no filter. s = [max(4, 2, 2), max(2, 0, 2), max(1.5, 1.5), |0 - 0| -> 1/4]
    assert band.kept(0.2) == (0, 1, 2)
    np.testing.assert_array_equal(band.statistics((0, 1, 2), "lower").scale, [4.0, 2.0, 1.5, 0.25])
    # delta 0.4: (3 + 1) 0.6 = 2.4 <= 3: gamma = np.quantile([4, 2, 2], 0.6) = 2.4 keeps a and b only; no kept
    # curve reaches t = 3: s = 1 / 3 there
    assert band.kept(0.4) == (1, 2)
    filtered = band.statistics((1, 2), "lower")
    np.testing.assert_allclose(filtered.scale, [2.0, 2.0, 1.5, 1.0 / 3.0])
    # band scores (mu - eta) / s: x max(0.5, 0.5, 1/3, -3) = 0.5; y max(-0.5, -0.5) = -0.5 -> k = np.quantile(0.6)
    np.testing.assert_allclose(filtered.band_scores, [0.5, -0.5])
    fitted = fit_threshold(curves, replace(AUTHORS, delta=0.4))
    assert fitted.params["k"] == pytest.approx(0.1)
    np.testing.assert_allclose(fitted.values, [2.2, 2.2, 1.65, 0.1 / 3.0])


def test_authors_band_with_shape_curves_is_as_long_as_the_longest_shape_curve() -> None:
    shape = [np.array([1.0, 3.0]), np.array([3.0, 5.0])]  # mu = [2, 4], s = [1, 1]
    curves = [np.array([2.5, 4.0, 9.0]), np.array([1.0])]  # I2; the third step of the first is past mu
    fitted = fit_threshold(curves, replace(AUTHORS, delta=0.5), shape_curves=shape)
    # scores (mu - eta) / s: max(-0.5, 0) = 0, max(1) = 1 -> k = np.quantile([0, 1], 0.5) = 0.5
    assert (fitted.params["m1"], fitted.params["m2"], fitted.params["k"]) == (2, 2, 0.5)
    np.testing.assert_array_equal(fitted.values, [2.5, 4.5])
    np.testing.assert_array_equal(fitted.over(4), [2.5, 4.5, 3.5, 3.5])  # the extension: their mean


def test_authors_band_needs_two_curves_and_a_known_rule() -> None:
    with pytest.raises(ThresholdError, match="at least 2"):
        fit_threshold([np.ones(3)], AUTHORS)
    with pytest.raises(ThresholdError, match="band_rule"):
        ThresholdSettings(band_rule="authors")


def _authors_oracle(curves: list[np.ndarray], delta: float, sign: float) -> np.ndarray:
    """The authors' CP band step by step from its description: Python lists, one ``np.mean`` per step."""
    pool = [list(map(float, c)) for c in curves]
    first = max(range(len(pool)), key=lambda i: len(pool[i]))
    longest = pool.pop(first)
    n1 = len(pool) // 2
    set1, set2 = [longest, *pool[:n1]], pool[n1:]
    mean = [float(np.mean([c[t] for c in set1 if len(c) > t])) for t in range(len(longest))]
    q = 1.0 - delta
    if (len(set1) + 1) * q > len(set1):
        kept = set1
    else:
        worst = [max(abs(c[t] - mean[t]) for t in range(len(c))) for c in set1]
        gamma = np.quantile(worst, q)
        kept = [c for c, w in zip(set1, worst) if w <= gamma]
    scale = []
    for t in range(len(mean)):
        reached = [abs(c[t] - mean[t]) for c in kept if len(c) > t]
        value = max(reached) if reached else 1 / t
        scale.append(1 / len(longest) if value < 1e-7 else value)
    scores = [max(sign * (c[t] - mean[t]) / scale[t] for t in range(min(len(c), len(mean)))) for c in set2]
    h = np.quantile(scores, q)
    return np.array([mean[t] + h * scale[t] for t in range(len(mean))])


@settings(max_examples=150, deadline=None, derandomize=True, database=None)
@given(st.integers(2, 40), st.sampled_from([0.01, 0.05, 0.1, 0.3, 0.5]), st.sampled_from(["lower", "upper"]),
       st.integers(0, 2**32 - 1), st.booleans())
def test_authors_band_equals_the_step_by_step_oracle_to_the_bit(m: int, delta: float, sign: str, seed: int,
                                                                ties: bool) -> None:
    rng = np.random.default_rng(seed)
    curves = [np.cumsum(rng.lognormal(size=int(rng.integers(1, 30)))) * 10.0 ** rng.uniform(-3, 3) for _ in range(m)]
    if ties:  # equal lengths, repeated values: ties in the split, zero deviations, the 1e-7 fill-in
        curves = [np.round(c[:5] if c.shape[0] >= 5 else np.resize(c, 5), 0) for c in curves]
    fitted = fit_threshold(curves, replace(AUTHORS, delta=delta, band_sign=sign))
    np.testing.assert_array_equal(fitted.values, _authors_oracle(curves, delta, 1.0 if sign == "upper" else -1.0))
