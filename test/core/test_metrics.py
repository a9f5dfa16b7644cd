"""Metrics, App. B.4."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fiper_ros.core.metrics import authors_rounding, evaluate


def test_hand_computed_metrics() -> None:
    # 3 failures: detected at 2 and 5, one missed; 2 successes: one false alarm.
    result = evaluate([2, 5, None, None, 1], [True, True, True, False, False], t_max=10)
    assert (result["tp"], result["fn"], result["tn"], result["fp"]) == (2, 1, 1, 1)
    assert result["tpr"] == pytest.approx(2 / 3)
    assert result["tnr"] == pytest.approx(0.5)
    assert result["acc"] == pytest.approx((2 / 3 + 0.5) / 2)
    assert result["dt"] == pytest.approx((0.2 + 0.5) / 2)
    assert result["twa"] == pytest.approx(0.5 * ((0.8 + 0.5) / 3 + 1 / 2))


def test_reference_detection_time_uses_t_max_minus_one() -> None:
    result = evaluate([3], [True], t_max=7, dt_mode="reference")
    assert result["dt"] == pytest.approx(3 / 6)
    assert evaluate([3], [True], t_max=7)["dt"] == pytest.approx(3 / 7)


def test_per_rollout_horizons() -> None:
    result = evaluate([1, 1], [True, True], t_max=[2, 4])
    assert result["dt"] == pytest.approx((0.5 + 0.25) / 2)


def test_one_class_sets_give_nan_for_the_undefined_half() -> None:
    only_successes = evaluate([None, 2], [False, False], t_max=5)
    assert math.isnan(only_successes["tpr"]) and math.isnan(only_successes["twa"]) and math.isnan(only_successes["acc"])
    assert only_successes["tnr"] == 0.5 and only_successes["twa_neg"] == 0.5
    assert math.isnan(only_successes["dt"])
    only_failures = evaluate([0], [True], t_max=5)
    assert math.isnan(only_failures["tnr"]) and only_failures["twa_pos"] == 1.0


def test_invalid_inputs() -> None:
    with pytest.raises(ValueError, match="outside"):
        evaluate([10], [True], t_max=10)
    with pytest.raises(ValueError, match="dt_mode"):
        evaluate([1], [True], t_max=10, dt_mode="other")
    with pytest.raises(ValueError, match="outcomes"):
        evaluate([1, 2], [True], t_max=10)


def test_every_count_by_hand() -> None:
    # failures: detected at 0 and 3, two missed; successes: three quiet, two false alarms (T = 5)
    result = evaluate([0, 3, None, None, None, None, None, 4, 2], [True] * 4 + [False] * 5, t_max=5)
    assert {k: result[k] for k in ("tp", "fn", "tn", "fp", "n_pos", "n_neg", "dt_mode")} == {
        "tp": 2, "fn": 2, "tn": 3, "fp": 2, "n_pos": 4, "n_neg": 5, "dt_mode": "paper"}
    assert result["tpr"] == 0.5 and result["tnr"] == 0.6 and result["acc"] == pytest.approx(0.55)
    assert result["dt"] == pytest.approx(0.3)  # (0 / 5 + 3 / 5) / 2
    assert result["twa_pos"] == pytest.approx(0.35)  # ((1 - 0) + (1 - 0.6)) / 4
    assert result["twa"] == pytest.approx(0.475)  # (0.35 + 0.6) / 2


def test_detection_time_at_the_shortest_horizons() -> None:
    # T = 1: the only step is 0, DT 0 in both modes (the reference mode's t / (T - 1) has no T - 1 = 0)
    for dt_mode in ("paper", "reference"):
        assert evaluate([0], [True], t_max=1, dt_mode=dt_mode)["dt"] == 0.0
    # T = 2: the reference mode divides by T - 1 = 1
    assert evaluate([1], [True], t_max=2, dt_mode="reference")["dt"] == 1.0
    assert evaluate([1], [True], t_max=2)["dt"] == 0.5


def test_rejections_say_what_was_wrong() -> None:
    with pytest.raises(ValueError, match=r"^t_max must be >= 1, got 0$"):
        evaluate([0], [True], t_max=0)
    with pytest.raises(ValueError, match=r"^2 t_max values but 1 outcomes$"):
        evaluate([0], [True], t_max=[3, 4])


# metrics_rule="reference": the authors' empty classes, TWA sum and rounding.
def _float32(value: float) -> float:
    return float(np.float32(value))


def test_reference_rule_with_an_empty_positive_class() -> None:
    # three successes, one false alarm: no positives, so TPR 0 and DT 1.0 (ours: NaN); TNR 2/3 -> 0.666667
    result = evaluate([None, 2, None], [False, False, False], t_max=5, dt_mode="reference", metrics_rule="reference")
    assert (result["tpr"], result["dt"], result["twa_pos"]) == (0.0, 1.0, 0.0)
    assert result["tnr"] == _float32(0.666667) == result["twa_neg"]
    assert result["acc"] == _float32(0.333333)  # (0 + 2/3) / 2, rounded
    assert result["twa"] == _float32(0.333333)  # (1/3 + 1/3) * 0.5: the empty class adds nothing
    paper = evaluate([None, 2, None], [False, False, False], t_max=5, dt_mode="reference")
    assert math.isnan(paper["tpr"]) and math.isnan(paper["dt"]) and math.isnan(paper["twa"])


def test_reference_rule_with_an_empty_negative_class_and_no_true_positive() -> None:
    result = evaluate([None, None], [True, True], t_max=5, dt_mode="reference", metrics_rule="reference")
    assert (result["tpr"], result["tnr"], result["acc"], result["dt"], result["twa"]) == (0.0, 0.0, 0.0, 1.0, 0.0)


def test_reference_rule_by_hand() -> None:
    # failures alarmed at 1 and 4 of T_max = 7 (DT 1/6, 4/6), one missed; successes: one quiet, one false alarm
    result = evaluate([1, None, 4, 3, None], [True, True, True, False, False], t_max=7, dt_mode="reference",
                      metrics_rule="reference")
    assert result["tpr"] == _float32(0.666667) and result["tnr"] == 0.5
    assert result["dt"] == _float32(np.round(np.mean([1 / 6, 4 / 6]), 6))  # 0.416667
    # TWA = 0.5 [(1 - 1/6) / 3 + (1 - 4/6) / 3 + 1 / 2] = 0.5 (0.277778 + 0.111111 + 0.5) = 0.444444
    assert result["twa"] == _float32(0.444444)
    assert result["acc"] == _float32(0.583333)  # (2/3 + 1/2) / 2 = 0.58333333


def test_authors_rounding_rounds_as_numpy_to_six_decimals_then_float32() -> None:
    # numpy's round (x 1e6, rint, / 1e6) takes 3.5e-6 to 4e-6; Python's round of the float gives 3e-6
    assert authors_rounding(3.5e-6) == _float32(4e-6)
    assert round(3.5e-6, 6) == 3e-6
    assert authors_rounding(1 / 3) == _float32(0.333333) == 0.33333298563957214
    with pytest.raises(ValueError, match="metrics_rule"):
        evaluate([1], [True], t_max=10, metrics_rule="authors")
