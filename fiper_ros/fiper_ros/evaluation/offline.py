"""The offline oracle: bag -> Rollouts -> :func:`fiper_ros.core.monitor.predict_rollout` -> the fusion node's
:class:`~fiper_ros.runtime.alarm.AlarmFuser`, no DDS.

``fiper replay --offline`` prints what the live suite would say; the replay test checks that the live
path (real node processes over DDS) says exactly this, step for step: every step's scores enter the same
state machine the fusion node runs (the votes, the latch, UNKNOWN for a missing threshold), in step order.
:func:`calibration_for` is how every command loads a calibration: refused with one line naming the file, and
checked against the bags or the policy it is used with (task, shapes, action space; a calibration whose detectors
read the action batches needs bags with them, an observation-only one takes any).
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import layout_of, read_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.core.calibration import Calibration, CalibrationMismatch, load_calibration
from fiper_ros.core.detectors import info
from fiper_ros.core.kinematics import ForwardKinematics, KinematicsError
from fiper_ros.core.monitor import RolloutPrediction, predict_rollout
from fiper_ros.evaluation.errors import EvaluationError
from fiper_ros.evaluation.results import RolloutResult, StepResult
from fiper_ros.interface.messages import OUTCOME_NAMES
from fiper_ros.policy.config import PolicyConfig
from fiper_ros.runtime.alarm import AlarmFuser, DetectorScore


def bag_layout(bag: Path) -> tuple[BagInfo, str]:
    """The task, shapes and action space of ``bag`` and how to name it."""
    with BagReader(bag) as reader:
        return layout_of(reader), f"bag {bag}"


def policy_layout(config: PolicyConfig, model: Path) -> tuple[BagInfo, str]:
    """What a policy of ``config`` publishes, and how to name it."""
    info = BagInfo(task=config.task, batch_size=config.sample_batch, horizon=config.horizon,
                   action_dim=config.action_dim, exec_steps=config.exec_steps, embedding_dim=config.embed_dim,
                   action_space=config.action_space)
    return info, f"the {config.task} policy {model}"


def check_fits(calibration: Calibration, calibration_dir: Path, layout: BagInfo, what: str) -> None:
    """Raise :class:`EvaluationError` if ``layout``'s task, embedding size, action shape or action space differ
    (fields the layout leaves empty are not checked), or if a declared detector reads the action batches and the
    layout has none."""
    if calibration.layout.has_actions and not layout.action_dim:
        readers = [info(d).label for d in calibration.detectors if info(d).reads == "actions"]
        raise EvaluationError(f"calibration {calibration_dir} declares {', '.join(calibration.detectors)}, but {what} has "
                       f"no action batches for {' and '.join(readers)}: use an observation-only calibration (fiper "
                       "calibrate --detectors rnd_oe)")
    try:
        calibration.check_compatible(
            embedding_dim=layout.embedding_dim or None, action_dim=layout.action_dim or None,
            horizon=layout.horizon or None, exec_steps=layout.exec_steps or None,
            action_space=layout.action_space or None, task=layout.task or None)
    except CalibrationMismatch as error:
        raise EvaluationError(f"calibration {calibration_dir} does not fit {what}: {error}") from error


def calibration_for(directory: Path, layouts: Sequence[tuple[BagInfo, str]]) -> Calibration:
    """The calibration in ``directory`` (refusal: one line naming the file), checked against ``layouts``."""
    calibration = load_calibration(directory)  # a CalibrationError names the file
    for layout, what in layouts:
        check_fits(calibration, directory, layout, what)
    return calibration


def predict_bag(bag: Path, calibration: Calibration, fk: ForwardKinematics | None = None) -> list[RolloutResult]:
    """FIPER over every rollout of ``bag`` (``fk``: the robot's FK, for joint-space actions)."""
    results = []
    for rollout in read_rollouts(bag):
        try:
            calibration.check_compatible(task=rollout.task)
            prediction = predict_rollout(rollout, calibration, fk)
        except CalibrationMismatch as error:
            raise EvaluationError(f"{bag}: rollout {rollout.rollout_id}: {error}") from error
        except KinematicsError as error:
            raise EvaluationError(f"{bag}: rollout {rollout.rollout_id}: {error}; give the robot model with --urdf "
                           "and --ee-frame") from error
        steps = fused_steps(prediction, int(rollout.rollout_id), calibration.settings.combine)
        results.append(RolloutResult(int(rollout.rollout_id), rollout.task, rollout.scenario,
                                     OUTCOME_NAMES[rollout.success], steps))
    return results


def fused_steps(prediction: RolloutPrediction, rollout_id: int, combine: str) -> dict[int, StepResult]:
    """Every step of one rollout as the fusion node says it: each step's scores, in step order, through the
    fusion node's own :class:`~fiper_ros.runtime.alarm.AlarmFuser` (the votes, the latch, UNKNOWN)."""
    detectors = tuple(prediction.detectors)
    fuser = AlarmFuser(combine, detectors=detectors, buffer_size=len(detectors) + 1)
    fuser.start(rollout_id, 0)
    steps = {}
    for t in range(prediction.alarms.shape[0]):
        state = None
        for name, trace in prediction.detectors.items():
            state = fuser.add(DetectorScore(name, rollout_id, t, float(trace.windowed[t]), float(trace.thresholds[t]),
                                            t, exceeded=bool(trace.exceeded[t])), t)
        assert state is not None  # every declared score of step t was added
        steps[t] = StepResult.of_state(state)
    return steps

