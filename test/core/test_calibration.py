"""Calibration fitting, files and compatibility checks."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.core_data import ACTION_DIM, EMBEDDING_DIM, HORIZON, TINY_RND, make_rollout

from fiper_ros.core.ace import action_ranges
from fiper_ros.core.calibration import (
    CALIBRATION_FILE,
    Calibration,
    CalibrationError,
    CalibrationMismatch,
    CalibrationSettings,
    calibrate,
    load_calibration,
)
from fiper_ros.core.rollout import Rollout


def test_fitted_fields(calibration: Calibration, calibration_rollouts: list[Rollout]) -> None:
    assert calibration.num_rollouts == 24  # the failed rollout is not used
    layout = (calibration.embedding_dim, calibration.action_dim, calibration.horizon)
    assert layout == (EMBEDDING_DIM, ACTION_DIM, HORIZON)
    good = [r.actions[..., :3] for r in calibration_rollouts if r.success]
    assert np.allclose(calibration.ranges, action_ranges(good))
    assert np.allclose(calibration.cell, 0.03 * calibration.ranges)
    longest = max(r.length for r in calibration_rollouts if r.success)
    assert calibration.threshold_obs.values.shape == (longest,)
    assert calibration.threshold_act.kind == "cp_band" and np.all(np.isfinite(calibration.threshold_act.values))


def test_save_load_round_trip(calibration: Calibration, tmp_path: Path) -> None:
    path = calibration.save(tmp_path)
    content = yaml.safe_load(path.read_text())
    for key in ("format_version", "settings", "delta", "windows", "threshold_kind", "ranges", "thresholds",
                "embedding_dim", "action_dim", "horizon", "exec_steps", "action_space", "content_hash"):
        assert key in content
    loaded = load_calibration(tmp_path)
    assert loaded.content_hash == calibration.content_hash == content["content_hash"]
    assert loaded.settings == calibration.settings
    assert np.array_equal(loaded.threshold_obs.values, calibration.threshold_obs.values)
    assert np.array_equal(loaded.threshold_act.values, calibration.threshold_act.values)
    assert np.array_equal(loaded.ranges, calibration.ranges)


def test_tampering_and_missing_files_are_refused(calibration: Calibration, tmp_path: Path) -> None:
    calibration.save(tmp_path / "good")
    with pytest.raises(CalibrationError, match="directory not found"):
        load_calibration(tmp_path / "absent")
    shutil.copytree(tmp_path / "good", tmp_path / "no_weights")
    (tmp_path / "no_weights" / "rnd_oe.pt").unlink()
    with pytest.raises(CalibrationError, match="rnd_oe.pt"):
        load_calibration(tmp_path / "no_weights")
    shutil.copytree(tmp_path / "good", tmp_path / "edited")
    path = tmp_path / "edited" / CALIBRATION_FILE
    content = yaml.safe_load(path.read_text())
    content["delta"] = 0.5
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(CalibrationError, match="content hash"):
        load_calibration(tmp_path / "edited")
    content["format_version"] = 2
    path.write_text(yaml.safe_dump(content))
    with pytest.raises(CalibrationError, match="format_version 2"):
        load_calibration(tmp_path / "edited")
    shutil.copytree(tmp_path / "good", tmp_path / "corrupt")
    (tmp_path / "corrupt" / "rnd_oe.pt").write_bytes(b"not a torch file")
    with pytest.raises(CalibrationError, match="rnd_oe.pt"):
        load_calibration(tmp_path / "corrupt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CalibrationError, match="calibration file not found"):
        load_calibration(tmp_path / "empty")


def test_check_compatible(calibration: Calibration) -> None:
    calibration.check_compatible(embedding_dim=EMBEDDING_DIM, action_dim=ACTION_DIM, horizon=HORIZON)
    with pytest.raises(CalibrationMismatch, match="embedding_dim: expected 12, got 64") as error:
        calibration.check_compatible(embedding_dim=64)
    assert (error.value.field, error.value.expected, error.value.got) == ("embedding_dim", 12, 64)
    with pytest.raises(CalibrationMismatch, match="horizon"):
        calibration.check_compatible(horizon=16)


def test_too_few_successes_are_refused(settings: CalibrationSettings) -> None:
    rng = np.random.default_rng(0)
    rollouts = [make_rollout(rng, i) for i in range(3)] + [make_rollout(rng, 9, success=False)]
    with pytest.raises(CalibrationError, match="at least 4 successful rollouts, got 3"):
        calibrate(rollouts, settings)
    with pytest.raises(CalibrationError, match="got 0"):
        calibrate([], settings)


def test_inconsistent_rollouts_are_refused(settings: CalibrationSettings) -> None:
    rng = np.random.default_rng(1)
    rollouts = [make_rollout(rng, i) for i in range(4)]
    odd = rollouts[2]
    rollouts[2] = dataclasses.replace(odd, actions=odd.actions[:, :, :4])
    with pytest.raises(CalibrationMismatch, match="horizon of rollout 'id-2'"):
        calibrate(rollouts, settings)


def test_reference_profile_takes_ranges_over_all_rollouts(calibration_rollouts: list[Rollout]) -> None:
    quick = dataclasses.replace(TINY_RND, max_epochs=2)
    settings = CalibrationSettings(rnd=quick, profile="reference", threshold="cp_constant")
    reference = calibrate(calibration_rollouts, settings)
    assert np.allclose(reference.ranges, action_ranges([r.actions[..., :3] for r in calibration_rollouts]))
    assert reference.threshold_obs.extension == "mean"
