"""Early detection, threshold-free: AUROC (ties 1/2), the q-AUC cut-off and each configuration's statistic."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fiper_ros.core.metrics import auroc, early_cut, rollout_peaks
from fiper_ros.core.thresholds import ThresholdSettings
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.early import TaskStatistics, areas, early_detection, statistic_of
from fiper_ros.evaluation.sweep import Group


def test_auroc_counts_a_tie_one_half() -> None:
    # failures {3, 2}, successes {1, 2}: 3>1, 3>2, 2>1 and the tie 2=2 -> (3 + 1/2) / 4
    assert auroc(np.array([3.0, 1.0, 2.0, 2.0]), [True, False, True, False]) == 0.875


def test_auroc_of_separated_inverted_and_constant_statistics() -> None:
    failed = [True, True, False, False, False]
    assert auroc(np.array([5.0, 4.0, 1.0, 2.0, 3.0]), failed) == 1.0
    assert auroc(np.array([0.0, 1.0, 4.0, 2.0, 3.0]), failed) == 0.0
    assert auroc(np.full(5, 7.0), failed) == 0.5


def test_auroc_is_computed_per_leading_row() -> None:
    rows = np.array([[3.0, 1.0, 2.0, 2.0], [0.0, 1.0, 0.0, 1.0]])
    np.testing.assert_array_equal(auroc(rows, [True, False, True, False]), [0.875, 0.0])


def test_auroc_with_an_empty_class_is_nan_of_the_right_shape() -> None:
    assert math.isnan(float(auroc(np.array([1.0, 2.0]), [True, True])))
    assert np.isnan(auroc(np.ones((3, 2)), [False, False])).all() and auroc(np.ones((3, 2)), [False, False]).shape == (3,)


def test_auroc_refuses_a_non_finite_statistic_and_mismatched_outcomes() -> None:
    with pytest.raises(ValueError, match="not finite"):
        auroc(np.array([1.0, np.nan]), [True, False])
    with pytest.raises(ValueError, match="do not match"):
        auroc(np.array([1.0, 2.0, 3.0]), [True, False])


@given(st.lists(st.tuples(st.integers(0, 4), st.booleans()), min_size=2, max_size=12))
def test_auroc_equals_the_pairwise_definition(pairs: list[tuple[int, bool]]) -> None:
    values = np.array([float(v) for v, _ in pairs])
    failed = [f for _, f in pairs]
    positives = [v for v, f in pairs if f]
    negatives = [v for v, f in pairs if not f]
    if not positives or not negatives:
        assert math.isnan(float(auroc(values, failed)))
        return
    wins = sum((p > n) + 0.5 * (p == n) for p in positives for n in negatives)
    assert float(auroc(values, failed)) == wins / (len(positives) * len(negatives))


def test_early_cut_is_the_ceiling_of_q_t_max() -> None:
    assert early_cut(10, 0.25) == 3 and early_cut(8, 0.25) == 2 and early_cut(8, 1.0) == 8 and early_cut(1, 0.01) == 1
    for q in (0.0, 1.5):
        with pytest.raises(ValueError, match="q must be in"):
            early_cut(8, q)


def test_rollout_peaks_see_only_each_rollouts_steps_and_the_cut() -> None:
    # rows past their length hold garbage (100) that must never count; rollout 1 is shorter than the cut
    curves = np.array([[1.0, 5.0, 2.0, 9.0], [4.0, 100.0, 100.0, 100.0], [0.0, 1.0, 7.0, 100.0]])
    lengths = [4, 1, 3]
    np.testing.assert_array_equal(rollout_peaks(curves, lengths), [9.0, 4.0, 7.0])
    np.testing.assert_array_equal(rollout_peaks(curves, lengths, cut=2), [5.0, 4.0, 1.0])
    with pytest.raises(ValueError, match="not finite"):
        rollout_peaks(np.array([[1.0, np.inf]]), [2])
    with pytest.raises(ValueError, match="do not fit"):
        rollout_peaks(curves, [4, 0, 3])


def test_q_auc_by_hand_with_a_rollout_shorter_than_the_cut() -> None:
    # T_max 8, q 0.25 -> cut 2. Failure a: quiet early, 10 late; failure b: one step of 3 (shorter than the cut);
    # success c: 1 throughout; success d: 0, 2, then 5.
    curves = np.zeros((4, 8))
    curves[0, 2:] = 10.0
    curves[1, 0] = 3.0
    curves[2, :] = 1.0
    curves[3, :4] = [0.0, 2.0, 5.0, 5.0]
    lengths = [8, 1, 8, 4]
    failed = [True, True, False, False]
    cut = early_cut(max(lengths), 0.25)
    # whole: failures {10, 3} vs successes {1, 5}: 10>1, 10>5, 3>1 -> 3/4; early: {0, 3} vs {1, 2}: 3>1, 3>2 -> 2/4
    assert auroc(rollout_peaks(curves, lengths), failed) == 0.75
    assert auroc(rollout_peaks(curves, lengths, cut), failed) == 0.5


def _stream(test: list[list[float]]) -> StreamScores:
    fit = [np.array([1.0, 1.0, 1.0]), np.array([1.0, 2.0, 3.0])]
    return StreamScores(fit=fit, conformal=[np.array([1.0, 1.0, 1.0])], test=[np.array(t) for t in test])


def test_a_single_stream_statistic_is_its_windowed_score_whatever_the_threshold_kind() -> None:
    # window 2 sums: failure [1, 3, 5] -> peak 5, early (T_max 3, q 0.5: cut 2) 3; success [0, 2] -> 2 and 2
    streams = {"rnd_oe": _stream([[1.0, 2.0, 3.0], [0.0, 2.0]])}
    statistics = TaskStatistics(streams, ThresholdSettings(), 0.5)
    groups = [Group("rnd_oe", "2", kind) for kind in ("cp_band", "time_varying")]
    whole, early = statistics.peaks(groups, {})
    np.testing.assert_array_equal(whole, [[5.0, 2.0], [5.0, 2.0]])
    np.testing.assert_array_equal(early, [[3.0, 2.0], [3.0, 2.0]])
    auc, q_auc = areas(whole, early, np.array([True, False]))
    np.testing.assert_array_equal(auc, [1.0, 1.0])
    np.testing.assert_array_equal(q_auc, [1.0, 1.0])


def test_statistics_of_combinations_and_fiper() -> None:
    combos = {"pair": ("rnd_oe", "ace"), "clock": ("rnd_oe", "elapsed")}
    assert statistic_of(Group("pair", "5", "cp_band", "and"), combos).votes == 2
    assert statistic_of(Group("pair", "5", "cp_band", "or"), combos).votes == 1
    assert statistic_of(Group("pair", "5", "cp_band", "kth:2"), combos).votes == 2
    clock = statistic_of(Group("clock", "5", "cp_band", "max"), combos)
    assert clock.labels == ("5", "cum") and clock.kinds == ("cp_band", "cp_scaled") and clock.votes == 1
    fiper = statistic_of(Group("fiper", "5/cum", "cp_scaled", "and"), combos)
    assert fiper.labels == ("5", "cum") and fiper.kinds == ("cp_scaled", "cp_scaled") and fiper.votes == 2
    # CP constant's shape (the fit part's maxima) puts them on one scale; time-varying thresholds have no shape
    assert statistic_of(Group("fiper", "5/5", "cp_constant", "and"), combos).kinds == ("cp_constant", "cp_constant")
    assert statistic_of(Group("fiper", "5/5", "time_varying", "and"), combos) is None
    assert statistic_of(Group("rnd_oe", "5", "cp_constant"), combos).kinds == (None,)


def test_a_combined_statistic_normalises_by_the_fit_parts_band() -> None:
    # band of the fit part (window 1): mu = [1, 1.5, 2], s = population std [0, 0.5, 1] floored; with two
    # detectors equal, AND (2 votes) and MAX (1 vote) give the same z; a configuration without statistic is NaN
    streams = {"rnd_oe": _stream([[1.0, 2.5, 4.0]]), "ace": _stream([[1.0, 2.5, 4.0]])}
    statistics = TaskStatistics(streams, ThresholdSettings(), 1.0)
    groups = [Group("pair", "1", "cp_band", "and"), Group("pair", "1", "cp_band", "max"),
              Group("fiper", "1/1", "time_varying", "or")]
    whole, _ = statistics.peaks(groups, {"pair": ("rnd_oe", "ace")})
    assert whole[0, 0] == whole[1, 0] == 2.0  # (2.5 - 1.5) / 0.5 = (4 - 2) / 1 = 2
    assert np.isnan(whole[2]).all()


def test_pooled_areas_put_each_tasks_raw_statistic_on_its_cp_constant_scale() -> None:
    # Two tasks, the second's scores 100 times the first's. Per task the failure peaks above the success (AUROC 1).
    # Pooled raw: failures {4, 300} vs successes {2.5, 250}: 4 < 250 -> 3/4. On each task's CP constant scale (fit
    # maxima {1, 3}: mean 2, std 1; {100, 300}: 200, 100): failures {2, 1} vs successes {0.5, 0.5} -> 1.
    def task(scale: float, failure: float) -> TaskStatistics:
        stream = StreamScores(fit=[np.array([scale]), np.array([3.0 * scale])], conformal=[np.array([scale])],
                              test=[np.array([failure]), np.array([2.5 * scale])])
        return TaskStatistics({"rnd_oe": stream}, ThresholdSettings(), 1.0)

    tasks = [task(1.0, 4.0), task(100.0, 300.0)]
    group = Group("rnd_oe", "1", "cp_band")
    failed = [np.array([True, False])] * 2
    found = early_detection({0: tasks}, {0: [group, group]}, failed, [None, None], {})
    np.testing.assert_array_equal(found.auroc, [[1.0], [1.0]])
    assert found.pooled_auroc[0] == found.pooled_q_auc[0] == 1.0
    assert tasks[1].pooling(group, {}) == (200.0, 100.0)
    # a normalised statistic (a combination's) is pooled as it is
    assert tasks[1].pooling(Group("pair", "1", "cp_band", "max"), {"pair": ("rnd_oe",)}) == (0.0, 1.0)
