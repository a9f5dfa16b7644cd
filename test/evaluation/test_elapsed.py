"""The elapsed-time baseline by hand: alarm at step k of every rollout longer than k, k the conformal
quantile of the calibration successes' lengths."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.calibration import split_successes
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.thresholds import conformal_quantile
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.methods import ELAPSED, MethodSettings
from fiper_ros.evaluation.protocol import alarm_metrics
from fiper_ros.evaluation.scoring import compute_streams
from fiper_ros.evaluation.sweep import Group, SweepSettings, sweep_task

CALIBRATION_LENGTHS = (2, 3, 4, 5, 6, 7, 8, 9, 10)
TEST = ((5, True), (10, True), (11, False), (15, False))  # (length, success)
DELTAS = (0.05, 0.1, 0.2)


def _rollout(name: str, length: int, success: bool) -> Rollout:
    return Rollout(rollout_id=name, task="hand", scenario="id", embeddings=np.zeros((length, 2)),
                   actions=np.zeros((length, 2, 2, 2)), exec_steps=1, success=success)


def _dataset() -> Dataset:
    calibration = [_rollout(f"cal-{i}", n, True) for i, n in enumerate(CALIBRATION_LENGTHS)]
    return Dataset("hand", calibration, [_rollout(f"test-{i}", n, s) for i, (n, s) in enumerate(TEST)])


def _alarms(split: str) -> tuple[list[Group], np.ndarray, np.ndarray]:
    settings = replace(MethodSettings.tiny(), split=split)
    streams, _ = compute_streams(_dataset(), [ELAPSED], settings, 0)
    # the sweep's windows and kinds do not matter: the baseline has its one configuration
    sweep = SweepSettings(windows=(3,), cumulative=False, deltas=DELTAS, kinds=("time_varying",))
    swept = sweep_task(streams, [ELAPSED], sweep, settings.calibration_settings(0).threshold_settings())
    return swept.groups, swept.alarms, swept.infinite


def test_same_data_alarms_computed_by_hand() -> None:
    groups, alarms, infinite = _alarms("same")
    assert groups == [Group(ELAPSED, "cum", "cp_constant")]
    # M = 9 lengths 2..10. delta 0.05: rank ceil(10 * 0.95) = 10 > 9, +inf, never alarms.
    # delta 0.1: rank 9, k = 10: eta(t) = t + 1 > 10 from t = 10 on, so lengths 11 and 15 alarm at step 10.
    # delta 0.2: rank 8, k = 9: lengths 10, 11 and 15 alarm at step 9; length 5 never.
    assert alarms[0].tolist() == [[-1, -1, -1, -1], [-1, -1, 10, 10], [-1, 9, 9, 9]]
    assert infinite[0].tolist() == [True, False, False]
    failed = np.array([not s for _, s in TEST])
    twa, acc, dt, tpr, tnr = alarm_metrics(alarms, failed, np.array([n for n, _ in TEST]), "paper")[0, 1]
    assert (tpr, tnr, acc) == (1.0, 1.0, 1.0)
    assert dt == pytest.approx((10 / 11 + 10 / 15) / 2)  # each rollout's own length
    assert twa == pytest.approx(0.5 * ((1 - 10 / 11) + (1 - 10 / 15)) / 2 + 0.5)


def test_split_conformal_uses_only_the_conformal_lengths() -> None:
    _, alarms, infinite = _alarms("split")
    split = split_successes(len(CALIBRATION_LENGTHS), MethodSettings().calibration_settings(0))
    lengths = [CALIBRATION_LENGTHS[i] for i in split.conformal]
    assert len(lengths) == 4  # round(0.5 * 9): too few for delta 0.1 (needs 9) and 0.05 (needs 19)
    assert infinite[0].tolist() == [True, True, False]
    k = conformal_quantile(lengths, 0.2)
    assert k == max(lengths)  # rank ceil(5 * 0.8) = 4 of 4
    expected = [int(k) if n > k else -1 for n, _ in TEST]
    assert alarms[0, 2].tolist() == expected and alarms[0, :2].tolist() == [[-1] * 4] * 2
