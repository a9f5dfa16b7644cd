"""Metrics, App. B.4."""

from __future__ import annotations

import math

import pytest

from fiper_ros.core.metrics import evaluate


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
