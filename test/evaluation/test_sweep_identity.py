"""The sweep reproduces the single-configuration path (core.calibration + core.monitor + core.metrics),
for the default split conformal calibration (with in-sample and with cross-fitted shapes), the cross-fitted
calibration and the paper's same-data one."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.calibration import CalibrationSettings, calibrate
from fiper_ros.core.detectors import ACE, RND_OE
from fiper_ros.core.metrics import evaluate
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.core.profiles import get_profile
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import horizons
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.protocol import METRICS, alarm_metrics
from fiper_ros.evaluation.scoring import compute_streams
from fiper_ros.evaluation.sweep import Group, SweepSettings, sweep_task

SEED = 2
SWEEP = SweepSettings(windows=(1, 2, 3, 5), cumulative=True, deltas=(0.1, 0.2, 0.3), pairs="full", max_pool=(2, 3))
CASES = {
    "paper": [
        Group("fiper", "3/3", "cp_band", "and"),
        Group("fiper", "2/5", "time_varying", "or"),
        Group("fiper", "cum/cum", "cp_constant", "and"),
        Group("fiper", "5/1", "cp_scaled", "or"),
        Group("rnd_oe", "5", "time_varying"),
        Group("rnd_oe", "2", "cp_scaled"),
        Group("ace", "1", "cp_band"),
        Group("rnd_oe", "max3", "cp_band"),
        Group("fiper", "max2/max2", "cp_scaled", "or"),
    ],
    "reference": [Group("fiper", "3/2", "cp_band", "and"), Group("ace", "cum", "time_varying"),
                  Group("rnd_oe", "3", "cp_scaled")],
}


def _single_path(dataset: Dataset, settings: MethodSettings, group: Group, delta: float) -> list[int | None]:
    """First alarm per test rollout from a calibration fitted for exactly this configuration."""
    w_obs, w_act = group.windows()
    detectors = (RND_OE, ACE) if group.method == "fiper" else (group.method,)
    windows = {RND_OE: w_obs or 1, ACE: w_act or w_obs or 1} if group.method == "fiper" else {}
    calibration = calibrate(dataset.calibration, CalibrationSettings(
        detectors=detectors, window=(w_act or w_obs or 1) if group.method == ACE else (w_obs or 1), windows=windows,
        aggregation=group.aggregation, threshold=group.kind,
        delta=delta, combine=group.combine or "and", rnd=settings.rnd, seed=SEED, profile=settings.profile,
        split=settings.split, shape_folds=settings.shape_folds), refuse_infinite=False)
    out: list[int | None] = []
    for rollout in dataset.test:
        out.append(predict_rollout(rollout, calibration).first_alarm_step)
    return out


@pytest.mark.parametrize(("profile", "split", "shape_folds"), [
    ("paper", "split", 0), ("reference", "split", 0), ("paper", "same", 0), ("reference", "same", 0),
    ("paper", "cross", 0), ("paper", "split", 3)])
def test_sweep_equals_single_configuration_path(tiny_dataset: Dataset, profile: str, split: str,
                                                shape_folds: int) -> None:
    settings = replace(MethodSettings.tiny(profile), split=split, shape_folds=shape_folds)
    assert CalibrationSettings().split == "split"  # the default calibration is the first case
    streams, _ = compute_streams(tiny_dataset, ["rnd_oe", "ace"], settings, SEED)
    assert (streams["ace"].fit is None) == (split != "split")
    base = settings.calibration_settings(SEED).threshold_settings()
    task_sweep = sweep_task(streams, ["rnd_oe", "ace", "fiper"], SWEEP, base)
    groups, alarms = task_sweep.groups, task_sweep.alarms
    dt_mode, metrics_rule = get_profile(profile).dt_mode, get_profile(profile).metrics_rule
    t_max = horizons(tiny_dataset, profile)
    metrics = alarm_metrics(alarms, tiny_dataset.failed, t_max, dt_mode, metrics_rule=metrics_rule)
    raised = infinite = 0
    cases = CASES[profile][:2] if split == "cross" or shape_folds else CASES[profile]  # K + 1 fits per calibration
    for group in cases:
        g = groups.index(group)
        for d, delta in enumerate(SWEEP.deltas):
            expected = _single_path(tiny_dataset, settings, group, delta)
            swept = [None if a < 0 else int(a) for a in alarms[g, d]]
            assert swept == expected, (group, delta)
            raised += sum(a is not None for a in expected)
            infinite += bool(task_sweep.infinite[g, d])
            reference = evaluate(expected, list(tiny_dataset.failed),
                                 t_max if isinstance(t_max, int) else t_max.tolist(), dt_mode, metrics_rule)
            np.testing.assert_array_equal(metrics[g, d], [reference[m] for m in METRICS])
    total = len(cases) * len(SWEEP.deltas) * len(tiny_dataset.test)
    assert 0 < raised < total  # the comparison covers both alarms and silent rollouts
    if profile == "paper":  # 6 conformal rollouts (split) are too few for delta = 0.1: +inf thresholds compared too
        assert 0 < infinite < len(cases) * len(SWEEP.deltas)


def test_an_or_at_promise_delta_is_calibrated_at_half_delta(tiny_dataset: Dataset) -> None:
    """``or_promise`` ``"delta"``: FIPER's OR in the column of delta decides as a calibration of that OR at delta / 2
    (what ``fiper calibrate --auto-promise delta`` fits); every other configuration as at ``"entry"``."""
    settings = MethodSettings.tiny("paper")
    streams, _ = compute_streams(tiny_dataset, ["rnd_oe", "ace"], settings, SEED)
    base = settings.calibration_settings(SEED).threshold_settings()
    sweep = replace(SWEEP, deltas=(0.2, 0.3, 0.4), windows=(1, 3), max_pool=(2,), pairs="diagonal")
    entry = sweep_task(streams, ["rnd_oe", "ace", "fiper"], sweep, base)
    halved = sweep_task(streams, ["rnd_oe", "ace", "fiper"], replace(sweep, or_promise="delta"), base)
    assert halved.groups == entry.groups
    ors = [g for g, group in enumerate(entry.groups) if group.combine == "or"]
    others = [g for g in range(len(entry.groups)) if g not in ors]
    np.testing.assert_array_equal(halved.alarms[others], entry.alarms[others])
    np.testing.assert_array_equal(halved.infinite[others], entry.infinite[others])
    compared = differ = 0
    for g in ors:
        group = entry.groups[g]
        for d, delta in enumerate(sweep.deltas):
            swept = [None if a < 0 else int(a) for a in halved.alarms[g, d]]
            assert swept == _single_path(tiny_dataset, settings, group, delta / 2), (group, delta)
            compared += 1
            differ += bool((halved.alarms[g, d] != entry.alarms[g, d]).any())
        assert not (entry.infinite[g] & ~halved.infinite[g]).any()  # +inf at delta stays +inf at delta / 2
    assert compared == 4 * 4 * 3 and differ > 0  # 4 labels x 4 kinds x 3 deltas; halving moved some alarms
    assert (halved.infinite[ors] & ~entry.infinite[ors]).any()  # 6 conformal rollouts: +inf at 0.1, not at 0.2
