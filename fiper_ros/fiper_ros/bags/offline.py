"""The offline oracle: bag -> Rollouts -> :func:`fiper_ros.core.monitor.predict_rollout`, no DDS.

``fiper replay --offline`` prints what the live suite would say; the replay test checks that the live
path (real node processes over DDS) says exactly this, step for step.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fiper_ros.bags.errors import BagError
from fiper_ros.bags.reader import BagReader
from fiper_ros.bags.results import ALARM, OK, OUTCOME_NAMES, UNKNOWN, RolloutResult, StepResult, as_float32
from fiper_ros.bags.rollouts import layout_of, read_rollouts
from fiper_ros.core.calibration import Calibration, CalibrationMismatch
from fiper_ros.core.kinematics import ForwardKinematics, KinematicsError
from fiper_ros.core.monitor import predict_rollout


def check_fits(calibration: Calibration, calibration_dir: Path, bag: Path) -> None:
    """Raise :class:`BagError` if the bag's embedding size, action shape or action space differ."""
    with BagReader(bag) as reader:
        info = layout_of(reader)
    try:
        calibration.check_compatible(embedding_dim=info.embedding_dim or None, action_dim=info.action_dim or None,
                                     horizon=info.horizon or None)
        if info.action_space and info.action_space != calibration.action_space:
            raise CalibrationMismatch("action_space", calibration.action_space, info.action_space)
    except CalibrationMismatch as error:
        raise BagError(f"calibration {calibration_dir} does not fit bag {bag}: {error}") from error


def predict_bag(bag: Path, calibration: Calibration, fk: ForwardKinematics | None = None) -> list[RolloutResult]:
    """FIPER over every rollout of ``bag`` (``fk``: the robot's FK, for joint-space actions)."""
    results = []
    for rollout in read_rollouts(bag):
        try:
            prediction = predict_rollout(rollout, calibration, fk)
        except CalibrationMismatch as error:
            raise BagError(f"{bag}: rollout {rollout.rollout_id}: {error}") from error
        except KinematicsError as error:
            raise BagError(f"{bag}: rollout {rollout.rollout_id}: {error}; give the robot model with --urdf "
                           "and --ee-frame") from error
        latched = np.logical_or.accumulate(prediction.alarms)
        # As the fusion node (runtime.alarm): the latch first, then a missing (infinite) threshold is UNKNOWN.
        calibrated = np.isfinite(prediction.obs_thresholds) & np.isfinite(prediction.act_thresholds)
        steps = {
            t: StepResult(ALARM if latched[t] else OK if calibrated[t] else UNKNOWN, bool(prediction.obs_exceeded[t]),
                          bool(prediction.act_exceeded[t]), as_float32(prediction.obs_windowed[t]),
                          as_float32(prediction.act_windowed[t]))
            for t in range(rollout.length)
        }
        results.append(RolloutResult(int(rollout.rollout_id), rollout.task, rollout.scenario,
                                     OUTCOME_NAMES[rollout.success], steps))
    return results
