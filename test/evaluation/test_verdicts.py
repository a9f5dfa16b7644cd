"""The verdicts of replay and launch (issue #25): each rollout's verdict against its outcome, the closing table of
TPR, TNR and detection steps per scenario, and which rollouts are the calibration's own. Counts by hand."""
from __future__ import annotations

import math

from fiper_ros.evaluation.results import RolloutResult, StepResult
from fiper_ros.evaluation.verdicts import (ALL, in_sample, in_sample_warning, rollout_line, table, tally, verdict)


def rollout(rollout_id: int, scenario: str, outcome: str, steps: int, alarm_from: int | None = None) -> RolloutResult:
    """A result of ``steps`` steps, latched ALARM from ``alarm_from`` on."""
    states = {t: StepResult("alarm" if alarm_from is not None and t >= alarm_from else "ok", (False, False), (1.0, 1.0))
              for t in range(steps)}
    return RolloutResult(rollout_id, "task", scenario, outcome, states)


RESULTS = [
    rollout(4, "ood", "failure", 10, alarm_from=2),   # true positive at 2 of 10
    rollout(1, "id", "success", 10),                  # true negative
    rollout(2, "id", "success", 10, alarm_from=4),    # false positive
    rollout(3, "id", "failure", 20, alarm_from=5),    # true positive at 5 of 20
    rollout(5, "ood", "failure", 10),                 # false negative
    rollout(6, "ood", "unknown", 10, alarm_from=1),   # no outcome: not counted
]


def test_each_rollout_gets_its_verdict() -> None:
    assert [verdict(r) for r in RESULTS] == ["detected (true positive)", "no false alarm (true negative)",
                                             "false alarm (false positive)", "detected (true positive)",
                                             "missed (false negative)", ""]
    assert rollout_line(RESULTS[3]) == "rollout 3 task/id: 20 steps, first alarm step 5, outcome failure: detected " \
                                       "(true positive)"
    assert rollout_line(RESULTS[5]).endswith("outcome unknown: no verdict (outcome not known)")


def test_the_table_counts_per_scenario_and_over_all() -> None:
    rows = tally(RESULTS)
    # scenarios sorted by name, whatever the order of the rollouts (live results come by rollout id)
    assert [(r.scenario, r.rollouts, r.unknown, r.tp, r.fn, r.tn, r.fp, r.detection_steps) for r in rows] == [
        ("id", 3, 0, 1, 0, 1, 1, (5,)), ("ood", 2, 1, 1, 1, 0, 0, (2,)), (ALL, 5, 1, 2, 1, 1, 1, (2, 5))]
    everything = rows[-1]
    assert (everything.tpr, everything.tnr, everything.mean_detection_step) == (2 / 3, 1 / 2, 3.5)
    assert math.isclose(everything.dt, (5 / 20 + 2 / 10) / 2)
    assert math.isnan(rows[1].tnr) and rows[1].to_dict()["tnr"] is None  # no success in "ood"
    assert table(rows) == [
        "verdicts on 5 rollouts with a known outcome (failures are positives: an alarm on a failure is a true "
        "positive):",
        "scenario         rollouts failures  TPR           successes  TNR           mean detection step",
        "id                      3        1  1.00 (1/1)            2  0.50 (1/2)    5.0 (DT 0.25)",
        "ood                     2        2  0.50 (1/2)            0  -             2.0 (DT 0.20)",
        "all                     5        3  0.67 (2/3)            2  0.50 (1/2)    3.5 (DT 0.23)",
        "1 rollout(s) without an outcome (no END, or END with OUTCOME_UNKNOWN): not counted"]


def test_without_scenarios_only_the_row_over_all() -> None:
    unnamed = [rollout(1, "", "success", 3), rollout(2, "unknown", "failure", 3)]
    assert [r.scenario for r in tally(unnamed)] == [ALL]
    mixed = [rollout(1, "id", "success", 3), rollout(2, "", "failure", 3)]
    assert [(r.scenario, r.rollouts, r.fn) for r in tally(mixed)] == [("id", 1, 0), ("(none)", 1, 1), (ALL, 2, 1)]
    (empty,) = tally([])
    assert (empty.rollouts, table([empty])[-1]) == (0, "all                     0        0  -                     0  "
                                                       "-             -")


def test_the_calibrations_own_rollouts_are_named() -> None:
    split = {"mode": "split", "fit": ["7", "8"], "conformal": ["9"]}
    assert in_sample(split, [9, 10, 7, 7]) == [7, 9]
    assert in_sample({"mode": "cross", "fit": [], "conformal": [], "folds": [["3"], ["4"]]}, [4, 5]) == [4]
    assert in_sample({}, [7]) == []  # a calibration written before its split was recorded
    assert in_sample_warning(split, [10, 11]) == ""
    assert in_sample_warning(split, [7, 8, 9, 10]) == (
        "warning: 3 of the 4 rollouts are the calibration's own (rollout 7, 8, 9): it was fitted on them, so their "
        "verdicts are in-sample and say nothing about new rollouts; judge FIPER on rollouts it was not calibrated on")
    many = {"fit": [str(i) for i in range(1, 8)]}
    assert "(rollout 1, 2, 3, 4, 5, ...)" in in_sample_warning(many, range(1, 8))
