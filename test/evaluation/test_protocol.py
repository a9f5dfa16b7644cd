"""Protocol pieces: the clean split, selection by mean TWA, averaging over deltas and seeds."""

from __future__ import annotations

import numpy as np

from fiper_ros.core.rollout import Rollout
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import horizons
from fiper_ros.evaluation.protocol import METRICS, alarm_metrics, run_protocol, validation_split
from fiper_ros.evaluation.sweep import Group


def test_validation_split_is_disjoint_stratified_and_seeded() -> None:
    failed = np.array([True] * 10 + [False] * 7)
    validation, report = validation_split(failed, seed=1)
    assert not set(validation) & set(report)
    assert sorted([*validation, *report]) == list(range(17))
    assert failed[validation].sum() == 5 and failed[report].sum() == 5
    np.testing.assert_array_equal(validation_split(failed, seed=1)[0], validation)
    assert not np.array_equal(validation_split(failed, seed=2)[0], validation)


def test_alarm_metrics_match_hand_computed_values() -> None:
    alarms = np.array([[[2, -1, 0, -1]]])  # one group, one delta, four rollouts
    failed = np.array([True, True, False, False])
    twa, acc, dt, tpr, tnr = alarm_metrics(alarms, failed, 10, "paper")[0, 0]
    assert (tpr, tnr, acc) == (0.5, 0.5, 0.5)
    assert dt == 0.2
    assert twa == 0.5 * ((1 - 0.2) / 2 + 0.5)


def test_alarm_metrics_of_an_empty_subset_are_nan() -> None:
    # A task without ID test successes (the shipped sample sets) has no held-out false-alarm rate: NaN, not a
    # crash (reshape(-1, 0) cannot resolve -1).
    alarms = np.array([[[2, -1, 0, -1]], [[1, 1, 1, 1]]])
    empty = alarm_metrics(alarms, np.array([True, True, False, False]), 10, "paper", np.array([], dtype=int))
    assert empty.shape == (2, 1, len(METRICS)) and np.isnan(empty[..., METRICS.index("tnr")]).all()


def test_alarm_metrics_with_the_reference_rule_give_the_authors_values_for_a_subset_without_failures() -> None:
    alarms = np.array([[[2, -1, 0, -1]]])
    failed = np.array([True, True, False, False])
    only_successes = np.array([2, 3])  # one false alarm, one quiet: TNR 0.5, no positives
    twa, acc, dt, tpr, tnr = alarm_metrics(alarms, failed, 10, "reference", only_successes, "reference")[0, 0]
    assert (twa, acc, dt, tpr, tnr) == (0.25, 0.25, 1.0, 0.0, 0.5)
    assert np.isnan(alarm_metrics(alarms, failed, 10, "reference", only_successes)[0, 0, METRICS.index("tpr")])


def _rollout(name: str, length: int, success: bool) -> Rollout:
    return Rollout(rollout_id=name, task="hand", scenario="id", embeddings=np.zeros((length, 2)),
                   actions=np.zeros((length, 2, 2, 2)), exec_steps=1, success=success)


def test_alarm_metrics_over_no_rollouts_are_nan() -> None:
    """A test set without ID successes has no held-out false-alarm rate: NaN (before: a reshape error)."""
    alarms = np.array([[[2, -1, 0], [1, 1, -1]], [[-1, -1, -1], [0, 0, 0]]])  # 2 groups, 2 deltas, 3 rollouts
    metrics = alarm_metrics(alarms, np.array([True, True, False]), 10, "paper", np.array([], dtype=int))
    assert metrics.shape == (2, 2, len(METRICS)) and np.isnan(metrics).all()


def test_detection_time_is_relative_to_each_rollouts_own_length() -> None:
    # App. B.4: a failed episode of length T flagged at t is predicted right at T - t of its T steps. A failure
    # that ends early (a block off the table, 20 steps) is judged on its own length, not on the 75-step limit.
    calibration = [_rollout("c0", 30, True), _rollout("c1", 40, True), _rollout("c2", 80, True)]
    test = [_rollout("early", 20, False), _rollout("limit", 75, False), _rollout("ok", 30, True)]
    dataset = Dataset("hand", calibration, test)
    assert horizons(dataset, "paper").tolist() == [20, 75, 30]
    alarms = np.array([[[10, 15, -1]]])
    dt = METRICS.index("dt")
    paper = alarm_metrics(alarms, dataset.failed, horizons(dataset, "paper"), "paper")[0, 0]
    assert paper[dt] == (10 / 20 + 15 / 75) / 2
    # the authors' code: the longest rollout over calibration and test, minus one
    assert horizons(dataset, "reference") == 80
    reference = alarm_metrics(alarms, dataset.failed, horizons(dataset, "reference"), "reference")[0, 0]
    assert reference[dt] == (10 / 79 + 15 / 79) / 2


def test_selection_maximises_mean_twa_and_reports_the_other_subset() -> None:
    groups = [Group("ace", "1", "cp_band"), Group("ace", "2", "cp_band"), Group("ace", "cum", "cp_band")]
    select = np.zeros((2, 3, 3, 4, len(METRICS)))  # tasks, seeds, groups, deltas, metrics
    select[:, :, 1, :, 0] = 0.9
    select[:, :, 2, :, 0] = 1.0  # best, but cumulative is not selectable by default
    report = np.random.default_rng(0).random(select.shape)
    result = run_protocol("clean", groups, select, report, ["ace"], default_window=1, default_kind="cp_band")
    assert result.selected["ace"].group == groups[1]
    np.testing.assert_allclose(result.selected["ace"].values, report[:, :, 1].mean(axis=2))
    assert result.default["ace"].group == groups[0]
    mean, std = result.selected["ace"].average()
    per_seed = report[:, :, 1].mean(axis=2).mean(axis=0)
    np.testing.assert_allclose(mean, per_seed.mean(axis=0))
    np.testing.assert_allclose(std, per_seed.std(axis=0))
    anywhere = run_protocol("paper", groups, select, report, ["ace"], 1, "cp_band", ("window", "cumulative"))
    assert anywhere.selected["ace"].group == groups[2]
