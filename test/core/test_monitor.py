"""Streaming monitors equal the vectorised rollout prediction bit for bit; missing, non-finite and
boundary steps are never judged below their threshold by accident."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from helpers.core_data import make_rollout, overflowing_rnd
from helpers.states import ALARM, OK

from fiper_ros.core.calibration import Calibration
from fiper_ros.core.detectors import ACE, RND_OE
from fiper_ros.core.monitor import DetectorMonitor, MonitorError, predict_rollout
from fiper_ros.core.scorers import RndOeScorer
from fiper_ros.core.scores import NonFiniteScore
from fiper_ros.core.thresholds import Threshold
from fiper_ros.core.window import WindowAccumulator
from fiper_ros.runtime.alarm import AlarmFuser, DetectorScore


def _observation(calibration: Calibration) -> DetectorMonitor:
    return DetectorMonitor(calibration, RND_OE)


def _replaced(calibration: Calibration, detector: str, **changes: object) -> Calibration:
    """``calibration`` with one detector's part changed (``scorer=...``, ``threshold=...``)."""
    part = calibration.part()
    detectors = {**part.detectors, detector: dataclasses.replace(part.detectors[detector], **changes)}
    return dataclasses.replace(calibration, tasks={"synthetic": dataclasses.replace(part, detectors=detectors)})


@pytest.mark.parametrize(("ood", "length"), [(False, None), (True, None), (False, 40)])
def test_streaming_equals_vectorised(calibration: Calibration, ood: bool, length: int | None) -> None:
    """The nodes' path (the two streaming monitors, the fusion node's fuser over their scores) equals the
    offline one (``predict_rollout`` and the latch as a running OR) at every step."""
    rollout = make_rollout(np.random.default_rng(int(ood) + (length or 0)), 0, ood=ood, success=not ood, length=length)
    prediction = predict_rollout(rollout, calibration)
    observation, action = _observation(calibration), DetectorMonitor(calibration, ACE)
    fuser = AlarmFuser(calibration.settings.combine)
    fuser.start(1, 0)
    obs_steps, act_steps, states = [], [], []
    for t in range(rollout.length):
        obs_steps.append(observation.update(t, rollout.embeddings[t]))
        act_steps.append(action.update(t, (rollout.actions[t], None)))
        for name, s in (("rnd_oe", obs_steps[-1]), ("ace", act_steps[-1])):
            state = fuser.add(DetectorScore(name, 1, t, s.windowed, s.threshold, t, s.complete, bool(s.exceeded)), t)
        states.append(state)
    for name, stream in ((RND_OE, obs_steps), (ACE, act_steps)):
        trace = prediction.detectors[name]
        assert np.array_equal([s.score for s in stream], trace.scores)
        assert np.array_equal([s.windowed for s in stream], trace.windowed)
        assert np.array_equal([s.threshold for s in stream], trace.thresholds)
        assert np.array_equal([s.exceeded for s in stream], trace.exceeded)
    latched = np.logical_or.accumulate(prediction.alarms)
    assert [s.state for s in states] == [ALARM if a else OK for a in latched]
    first = next((s.step for s in states if s.state == ALARM), None)
    assert first == prediction.first_alarm_step and (first is not None) == ood


def test_ood_failure_is_flagged_and_id_success_is_not(calibration: Calibration) -> None:
    rng = np.random.default_rng(21)
    assert predict_rollout(make_rollout(rng, 1, ood=True, success=False), calibration).first_alarm_step is not None
    quiet = [predict_rollout(make_rollout(rng, i), calibration).first_alarm_step is None for i in range(10)]
    assert sum(quiet) >= 6


def test_steps_must_be_consecutive(calibration: Calibration) -> None:
    rollout = make_rollout(np.random.default_rng(2), 0)
    monitor = _observation(calibration)
    monitor.update(0, rollout.embeddings[0])
    with pytest.raises(MonitorError, match="expected policy step 1, got 2"):
        monitor.update(2, rollout.embeddings[2])
    monitor.reset()
    assert monitor.update(0, rollout.embeddings[0]).step == 0


def test_mismatched_inputs_are_refused(calibration: Calibration) -> None:
    from fiper_ros.core.calibration import CalibrationMismatch

    with pytest.raises(CalibrationMismatch, match="embedding_dim"):
        _observation(calibration).update(0, np.zeros(5))
    with pytest.raises(CalibrationMismatch, match="horizon"):
        DetectorMonitor(calibration, ACE).update(0, (np.zeros((8, 3, 4)), None))
    with pytest.raises(MonitorError, match=r"actions must be \[B, H, D\]"):
        DetectorMonitor(calibration, ACE).update(0, (np.zeros((3, 4)), None))


def test_joint_velocity_rollouts_stream_like_they_replay(tmp_path_factory: pytest.TempPathFactory) -> None:
    import dataclasses

    from helpers.core_data import TINY_RND
    from helpers.urdfs import PLANAR_URDF

    from fiper_ros.core.calibration import CalibrationSettings, calibrate
    from fiper_ros.core.kinematics import PinocchioFK
    from fiper_ros.core.rollout import Rollout

    path = tmp_path_factory.mktemp("urdf") / "planar2.urdf"
    path.write_text(PLANAR_URDF)
    fk = PinocchioFK(path, "tip")
    rng = np.random.default_rng(5)

    def velocity_rollout(index: int) -> Rollout:
        base = make_rollout(rng, index, length=12)
        joints = rng.uniform(-1, 1, size=(12, 2))
        return dataclasses.replace(
            base, actions=base.actions[..., :2], action_space="joint_velocity", metadata={"joint_positions": joints}
        )

    settings = CalibrationSettings(
        rnd=dataclasses.replace(TINY_RND, max_epochs=3), control_dt=0.1, threshold="time_varying", min_rollouts=4
    )
    calibration = calibrate([velocity_rollout(i) for i in range(6)], settings, fk=fk)
    rollout = velocity_rollout(10)
    prediction = predict_rollout(rollout, calibration, fk)
    monitor = DetectorMonitor(calibration, ACE, fk=fk)
    joints = rollout.metadata["joint_positions"]
    streamed = [monitor.update(t, (rollout.actions[t], joints[t])).windowed for t in range(rollout.length)]
    assert np.array_equal(streamed, prediction.detectors[ACE].windowed)
    ranges = calibration.scorer(ACE).ranges
    assert ranges.shape == (3,) and ranges[2] == 0.0  # planar arm: EE z is constant


def test_skipped_steps_enter_the_window_as_missing(calibration: Calibration) -> None:
    rollout = make_rollout(np.random.default_rng(3), 0, length=8)
    full = predict_rollout(rollout, calibration)
    monitor = _observation(calibration)  # w_O = 3
    assert monitor.update(0, rollout.embeddings[0]).complete
    monitor.skip_to(3)  # steps 1 and 2 were lost
    assert monitor.next_step == 3
    results = {t: monitor.update(t, rollout.embeddings[t]) for t in range(3, 8)}
    assert [results[t].complete for t in range(3, 8)] == [False, False, True, True, True]
    assert results[3].windowed == full.detectors[RND_OE].scores[3]  # a lower bound while steps are missing
    assert [results[t].windowed for t in (5, 6, 7)] == full.detectors[RND_OE].windowed[5:].tolist()


def _with_obs_threshold(calibration: Calibration, value: float) -> Calibration:
    return _replaced(calibration, RND_OE, threshold=Threshold("cp_constant", 0.05, np.array([value])))


def test_a_windowed_score_equal_to_its_threshold_is_not_exceeded(calibration: Calibration) -> None:
    # eq. (3) is strict; a ">=" anywhere in the streaming or vectorised path flips these.
    rollout = make_rollout(np.random.default_rng(3), 0)
    eta = _observation(calibration).update(0, rollout.embeddings[0]).windowed
    at = _with_obs_threshold(calibration, eta)
    below = _with_obs_threshold(calibration, float(np.nextafter(eta, -np.inf)))
    assert not _observation(at).update(0, rollout.embeddings[0]).exceeded
    assert _observation(below).update(0, rollout.embeddings[0]).exceeded
    assert not predict_rollout(rollout, at).detectors[RND_OE].exceeded[0]
    assert predict_rollout(rollout, below).detectors[RND_OE].exceeded[0]


def test_the_shipped_style_nan_case_now_scores_and_exceeds(calibration: Calibration) -> None:
    # Issue #27: an embedding of finite float32 values 3e38 scored NaN, "not exceeded", and the step was OK.
    monitor = _observation(calibration)
    result = monitor.update(0, np.full(calibration.layout.embedding_dim, 3e38, np.float32))
    assert np.isfinite(result.score) and np.isfinite(result.windowed) and result.exceeded


def test_a_non_finite_score_is_raised_and_the_step_can_be_declared_missing(calibration: Calibration) -> None:
    rollout = make_rollout(np.random.default_rng(4), 0)
    broken = _replaced(calibration, RND_OE,
                       scorer=RndOeScorer(overflowing_rnd(calibration.layout.embedding_dim), calibration.profile))
    monitor = _observation(broken)
    with pytest.raises(NonFiniteScore, match="RND-OE score"):
        monitor.update(0, rollout.embeddings[0])
    assert monitor.next_step == 0  # nothing was consumed, nothing entered the window
    missing = monitor.missing(0)
    assert np.isnan(missing.score) and missing.windowed == 0.0 and not missing.complete and not missing.exceeded
    assert monitor.next_step == 1
    with pytest.raises(NonFiniteScore, match="step 0"):
        predict_rollout(rollout, broken)


def test_missing_steps_give_lower_bounds_until_they_leave_the_window(calibration: Calibration) -> None:
    rollout = make_rollout(np.random.default_rng(5), 0, length=12)
    w = calibration.settings.window_of(RND_OE)
    monitor = _observation(calibration)
    first = monitor.update(0, rollout.embeddings[0])
    missing = monitor.missing(1)
    assert missing.windowed == first.score and not missing.complete  # s_0 + 0: a lower bound
    results = [monitor.update(t, rollout.embeddings[t]) for t in range(2, 2 + w)]
    assert [r.complete for r in results] == [False] * (w - 1) + [True]  # step 1 leaves the window at 1 + w


def test_a_huge_step_gap_costs_at_most_a_window_of_pushes(calibration: Calibration,
                                                          monkeypatch: pytest.MonkeyPatch) -> None:
    # Issue #18: a message with step 4294967295 made the old skip_to push one 0 per missing step (4e9 pushes).
    pushes = []
    original = WindowAccumulator.push

    def counted(self: WindowAccumulator, score: float) -> float:
        pushes.append(score)
        if len(pushes) > 100:
            raise AssertionError("skip_to pushes once per skipped step")
        return original(self, score)

    monkeypatch.setattr(WindowAccumulator, "push", counted)
    rollout = make_rollout(np.random.default_rng(6), 0)
    monitor = _observation(calibration)
    monitor.update(0, rollout.embeddings[0])
    monitor.skip_to(2**32 - 1)
    result = monitor.update(2**32 - 1, rollout.embeddings[1])
    assert result.windowed == result.score and not result.complete  # the window holds zeros and this step
    assert len(pushes) == 2


def test_a_detector_that_reads_the_step_before_marks_the_step_after_a_gap_incomplete(
        calibration_rollouts: list, tmp_path_factory: pytest.TempPathFactory) -> None:
    """Action consistency compares a step's chunk with the one before: the step after a lost one has no previous
    chunk (score 0, a lower bound), so the windows holding its score are incomplete: one step more than for a
    detector that reads its own step alone."""
    from helpers.core_data import TINY_RND

    from fiper_ros.core.calibration import CalibrationSettings, calibrate

    fitted = calibrate(calibration_rollouts, CalibrationSettings(rnd=TINY_RND, detectors=(RND_OE, "consistency"),
                                                                 window=2, delta=0.2))
    rollout = calibration_rollouts[0]
    monitor = DetectorMonitor(fitted, "consistency")
    assert monitor.update(0, (rollout.actions[0], None)).score == 0.0  # no chunk before step 0
    monitor.skip_to(3)
    results = [monitor.update(t, (rollout.actions[t], None)) for t in range(3, 7)]
    assert results[0].score == 0.0  # no chunk before: the lost step 2's
    # step 3's score reads the lost step 2, step 4's window (w 2) holds step 3's score, step 5's reads steps 3-5
    assert [r.complete for r in results] == [False, False, True, True]
    assert results[1].score == predict_rollout(rollout, fitted).detectors["consistency"].scores[4]


def test_an_equalised_joint_combine_streams_as_it_predicts(calibration_rollouts: list) -> None:
    """Tails equalised (max over RND-OE, progress and the elapsed time): the streaming monitors and the fusion node's
    fuser decide every step as predict_rollout does; the equalisation lives in the thresholds, nowhere else."""
    from helpers.core_data import TINY_RND

    from fiper_ros.core.calibration import CalibrationSettings, calibrate
    from fiper_ros.core.monitor import rollout_value

    detectors = (RND_OE, "progress", "elapsed")
    fitted = calibrate(calibration_rollouts, CalibrationSettings(rnd=TINY_RND, detectors=detectors, combine="max",
                                                                 window=3, delta=0.2, equalise="tail"))
    assert all("equaliser" in fitted.threshold(d).params for d in detectors)
    alarmed = 0
    for rollout in [*calibration_rollouts[:2], make_rollout(np.random.default_rng(3), 50, ood=True, success=False)]:
        prediction = predict_rollout(rollout, fitted)
        monitors = {d: DetectorMonitor(fitted, d) for d in detectors}
        fuser = AlarmFuser("max", detectors=detectors)
        fuser.start(1, 0)
        states = []
        for t in range(rollout.length):
            for d, monitor in monitors.items():
                s = monitor.update(t, rollout_value(rollout, d, t))
                assert (s.windowed, s.threshold, s.exceeded) == (prediction.detectors[d].windowed[t],
                                                                 prediction.detectors[d].thresholds[t],
                                                                 prediction.detectors[d].exceeded[t])
                state = fuser.add(DetectorScore(d, 1, t, s.windowed, s.threshold, t, s.complete, bool(s.exceeded)), t)
            states.append(state.state)
        assert states == [ALARM if a else OK for a in np.logical_or.accumulate(prediction.alarms)]
        alarmed += bool(prediction.alarms.any())
    assert alarmed >= 1  # the out-of-distribution rollout alarms: the comparison covers ALARM states
