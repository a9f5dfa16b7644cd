"""Observation-only calibrations: RND-OE alone, fitted on rollouts with or without action batches, saved and
loaded (the pair's calibrations keep their files and hashes), and judged by RND-OE's exceedance alone in the
streaming monitor, the vectorised prediction and the fusion."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.core_data import make_rollout

from fiper_ros.core.calibration import (
    Calibration,
    CalibrationError,
    CalibrationSettings,
    calibrate,
    guarantee,
    load_calibration,
    promised_rate,
)
from fiper_ros.core.calibration.settings import OPTION_OWNERS
from fiper_ros.core.calibration_file import declared_detectors
from fiper_ros.core.detectors import ACE, DETECTORS, OBSERVATION_ONLY, RND_OE, check_pair_format
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import fuse, fuse_declared
from fiper_ros.core.monitor import DetectorMonitor, MonitorError, predict_rollout
from fiper_ros.core.rollout import Rollout, RolloutSet


def _without_actions(rollout: Rollout) -> Rollout:
    return dataclasses.replace(rollout, actions=None)


@pytest.fixture(scope="module")
def observation_settings(settings: CalibrationSettings) -> CalibrationSettings:
    return dataclasses.replace(settings, detectors=OBSERVATION_ONLY)


@pytest.fixture(scope="module")
def observation_only(calibration_rollouts: list[Rollout], observation_settings: CalibrationSettings) -> Calibration:
    return calibrate([_without_actions(r) for r in calibration_rollouts], observation_settings)


def test_detector_sets_by_hand() -> None:
    assert check_pair_format(["ace", "rnd_oe"]) == DETECTORS == ("rnd_oe", "ace")
    assert check_pair_format([" rnd_oe ".strip()]) == OBSERVATION_ONLY == ("rnd_oe",)
    for bad in (["ace"], [], ["rnd_oe", "rnd_oe"], ["rnd_oe", "logpzo"]):
        with pytest.raises(ChoiceError, match="unsupported detectors .*: declare rnd_oe,ace or rnd_oe"):
            check_pair_format(bad)
    assert CalibrationSettings(detectors=("elapsed", "ace", "rnd_oe")).detectors == ("rnd_oe", "ace", "elapsed")
    for bad in ((), ("rnd_oe", "rnd_oe")):
        with pytest.raises(CalibrationError, match="declare each detector once, at least one"):
            CalibrationSettings(detectors=bad)
    with pytest.raises(CalibrationError, match="nope"):
        CalibrationSettings(detectors=("nope",))


@pytest.mark.parametrize("combine", ["and", "or"])
def test_one_detector_alone_is_its_own_decision(combine: str) -> None:
    decisions = np.array([False, True, True, False])
    assert fuse_declared([decisions], combine).tolist() == decisions.tolist()
    other = np.array([True, True, False, False])
    assert fuse_declared([decisions, other], combine).tolist() == fuse(decisions, other, combine).tolist()
    with pytest.raises(ValueError):
        fuse_declared([], combine)


def test_rnd_oe_alone_promises_its_thresholds_delta_whatever_the_combine(settings: CalibrationSettings) -> None:
    for combine in ("and", "or"):
        alone = dataclasses.replace(settings, detectors=OBSERVATION_ONLY, combine=combine, threshold="cp_constant")
        assert promised_rate(alone) == settings.delta
        assert guarantee(alone) == guarantee(dataclasses.replace(alone, combine="and"))
    assert promised_rate(dataclasses.replace(settings, combine="or")) == 2 * settings.delta  # the pair's OR


def test_an_observation_only_calibration_has_no_ace_part(observation_only: Calibration) -> None:
    assert observation_only.detectors == OBSERVATION_ONLY and not observation_only.layout.has_actions
    assert (observation_only.layout.action_dim, observation_only.layout.horizon, observation_only.layout.exec_steps,
            observation_only.layout.action_space) == (0, 0, 0, "")
    assert set(observation_only.part().split["behind_thresholds"]) == {RND_OE}
    assert set(observation_only.part().detectors) == {RND_OE}
    with pytest.raises(CalibrationError, match="'ace' is not calibrated here"):
        observation_only.threshold(ACE)
    # no action layout to check: data with any action batches, or none, fits it
    observation_only.check_compatible(embedding_dim=observation_only.layout.embedding_dim, action_dim=99, horizon=7,
                                      exec_steps=3, action_space="joint_velocity")


def test_it_is_fitted_alike_with_or_without_the_action_batches(
        calibration_rollouts: list[Rollout], observation_settings: CalibrationSettings,
        observation_only: Calibration, calibration: Calibration) -> None:
    """Any-policy data: the action batches of the rollouts do not change an observation-only calibration, and
    its RND-OE part is the full calibration's (the same network and threshold on the same rollouts)."""
    with_actions = calibrate(calibration_rollouts, observation_settings)
    assert with_actions.content_hash == observation_only.content_hash
    assert observation_only.scorer(RND_OE).digest() == calibration.scorer(RND_OE).digest()
    assert np.array_equal(observation_only.threshold(RND_OE).values, calibration.threshold(RND_OE).values)


def test_saved_and_loaded_without_ace_entries(observation_only: Calibration, tmp_path: Path) -> None:
    path = observation_only.save(tmp_path / "cal")
    content = yaml.safe_load(path.read_text())
    assert content["settings"]["detectors"] == ["rnd_oe"]
    assert not {option for option, owner in OPTION_OWNERS.items() if owner == ACE} & set(content["settings"])
    assert set(next(iter(content["tasks"].values()))["detectors"]) == {RND_OE} and content["layout"] == {"embedding_dim": observation_only.layout.embedding_dim}
    loaded = load_calibration(tmp_path / "cal")
    assert loaded.content_hash == observation_only.content_hash == content["content_hash"]
    assert loaded.detectors == OBSERVATION_ONLY and not loaded.layout.has_actions
    assert declared_detectors(tmp_path / "cal") == OBSERVATION_ONLY


def test_an_edited_detector_list_is_refused(observation_only: Calibration, tmp_path: Path) -> None:
    path = observation_only.save(tmp_path / "cal")
    path.write_text(path.read_text().replace("  detectors:\n  - rnd_oe\n", "  detectors:\n  - ace\n"))
    with pytest.raises(CalibrationError, match="calibration.yaml: missing entry 'ace'"):
        load_calibration(tmp_path / "cal")
    assert declared_detectors(tmp_path / "cal") == (ACE,)  # what the file says; loading it checks the hash


def test_a_missing_calibration_is_named(tmp_path: Path) -> None:
    with pytest.raises(CalibrationError, match=f"calibration directory not found: {tmp_path / 'none'}"):
        declared_detectors(tmp_path / "none")


def test_fipers_pair_needs_action_batches(calibration_rollouts: list[Rollout], settings: CalibrationSettings) -> None:
    rollouts = [*calibration_rollouts[:-2], _without_actions(calibration_rollouts[-2])]
    with pytest.raises(CalibrationError, match=r"rollout 'id-23' has no action batches, which ACE read: .* "
                                               r"\(fiper calibrate --detectors rnd_oe\)"):
        calibrate(rollouts, settings)


def test_prediction_is_rnd_oes_exceedance_alone(observation_only: Calibration, calibration: Calibration) -> None:
    rng = np.random.default_rng(3)
    rollout = make_rollout(rng, 0, ood=True, success=False, length=30)
    alone = predict_rollout(_without_actions(rollout), observation_only)
    assert set(alone.detectors) == {RND_OE}
    assert np.array_equal(alone.alarms, alone.detectors[RND_OE].exceeded) and alone.alarms.any()
    full = predict_rollout(rollout, calibration)  # the same RND-OE numbers as the pair's
    for name in ("scores", "windowed", "thresholds", "exceeded"):
        assert np.array_equal(getattr(alone.detectors[RND_OE], name), getattr(full.detectors[RND_OE], name)), name
    assert np.array_equal(predict_rollout(rollout, observation_only).alarms, alone.alarms)  # batches ignored
    with pytest.raises(MonitorError, match="has no action batches, which the calibration's detectors read"):
        predict_rollout(_without_actions(rollout), calibration)


def test_the_streaming_monitor_equals_the_prediction(observation_only: Calibration) -> None:
    rollout = _without_actions(make_rollout(np.random.default_rng(4), 1, ood=True, success=False, length=30))
    prediction = predict_rollout(rollout, observation_only)
    monitor = DetectorMonitor(observation_only, RND_OE)
    steps = [monitor.update(t, rollout.embeddings[t]) for t in range(rollout.length)]
    assert [s.exceeded for s in steps] == prediction.alarms.tolist()  # RND-OE alone: its exceedance is the alarm
    assert [s.windowed for s in steps] == prediction.detectors[RND_OE].windowed.tolist()
    with pytest.raises(CalibrationError, match="'ace' is not calibrated here"):
        DetectorMonitor(observation_only, ACE)


def test_a_rollout_without_action_batches_round_trips_through_npz(tmp_path: Path) -> None:
    rollout = _without_actions(make_rollout(np.random.default_rng(5), 2))
    assert not rollout.has_actions
    RolloutSet(calibration=[rollout]).save_npz(tmp_path / "set.npz")
    (loaded,) = RolloutSet.load_npz(tmp_path / "set.npz").calibration
    assert loaded.actions is None and np.array_equal(loaded.embeddings, rollout.embeddings)
