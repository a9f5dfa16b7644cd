"""Calibration fitting, files and compatibility checks; every damage class of helpers.calibration_damage
is refused on load with one line naming the file (docs/reliability.md, "Bags and calibration files")."""

from __future__ import annotations

import dataclasses
import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from helpers.calibration_damage import CALIBRATION_DAMAGES, FIT_DAMAGES, fit_damages
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
from fiper_ros.core.calibration_file import declared_detectors
from fiper_ros.core.detectors import DETECTORS
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.scores import act_scores, rollout_positions
from fiper_ros.core.thresholds import GUARANTEED_KINDS, fit_threshold
from fiper_ros.core.window import aggregate

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted([*ROOT.glob("models/*/calibration"), *ROOT.glob("bags/*/calibration")])


def test_fitted_fields(calibration: Calibration, calibration_rollouts: list[Rollout]) -> None:
    assert calibration.num_rollouts == 24  # the failed rollout is not used
    layout = (calibration.embedding_dim, calibration.action_dim, calibration.horizon)
    assert layout == (EMBEDDING_DIM, ACTION_DIM, HORIZON)
    # split conformal (the default): R_d from the rollouts that fitted the models, none of the conformal set
    split = calibration.split
    assert split["mode"] == "split" and len(split["fit"]) == len(split["conformal"]) == 12
    assert not set(split["fit"]) & set(split["conformal"])
    fitted = [r.actions[..., :3] for r in calibration_rollouts if r.success and str(r.rollout_id) in split["fit"]]
    assert np.allclose(calibration.ranges, action_ranges(fitted))
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


@pytest.fixture(scope="module")
def saved(calibration: Calibration, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The fitted calibration as a directory."""
    directory = tmp_path_factory.mktemp("saved") / "calibration"
    calibration.save(directory)
    return directory


@pytest.mark.parametrize("damage", CALIBRATION_DAMAGES)
def test_a_damaged_calibration_directory_is_refused_with_one_line_naming_the_file(
        damage: str, saved: Path, tmp_path: Path) -> None:
    directory = tmp_path / "calibration"
    shutil.copytree(saved, directory)
    expected = CALIBRATION_DAMAGES[damage](directory)
    with pytest.raises(CalibrationError) as error:
        load_calibration(directory)
    assert str(error.value).startswith(expected) and "\n" not in str(error.value), str(error.value)


@pytest.mark.parametrize("damage", FIT_DAMAGES)
def test_a_calibration_of_other_data_loads_and_names_what_differs(damage: str, saved: Path, tmp_path: Path) -> None:
    directory = tmp_path / "calibration"
    shutil.copytree(saved, directory)
    expected = fit_damages(saved, ROOT / "models" / "sorting" / "calibration")[damage](directory)
    fitting = load_calibration(saved)
    with pytest.raises(CalibrationMismatch) as error:
        load_calibration(directory).check_compatible(
            embedding_dim=fitting.embedding_dim, action_dim=fitting.action_dim, horizon=fitting.horizon,
            exec_steps=fitting.exec_steps, action_space=fitting.action_space, task=fitting.task)
    assert str(error.value).startswith(expected), str(error.value)


def test_the_task_is_recorded_and_rollouts_of_several_tasks_are_refused(
        calibration: Calibration, calibration_rollouts: list[Rollout], settings: CalibrationSettings) -> None:
    assert calibration.task == "synthetic"
    calibration.check_compatible(task="")  # a caller that does not know the task checks nothing
    mixed = [dataclasses.replace(r, task="other") if i == 3 else r for i, r in enumerate(calibration_rollouts)]
    with pytest.raises(CalibrationError, match=r"calibration rollouts of several tasks \(other, synthetic\)"):
        calibrate(mixed, settings)


def _content(directory: Path) -> dict[str, Any]:
    return yaml.safe_load((directory / CALIBRATION_FILE).read_text())


WITHOUT_TASK = [d for d in SHIPPED if "task" not in _content(d)]
MODELS_CALIBRATIONS = sorted(ROOT.glob("models/*/calibration*"))


@pytest.mark.parametrize("directory", WITHOUT_TASK, ids=lambda d: str(d.relative_to(ROOT)))
def test_shipped_calibrations_without_a_task_keep_their_content_hash(directory: Path) -> None:
    """Written before the task (and the detectors, issue #19) were recorded: they still load, with their stored
    hash, fit any task and declare FIPER's pair."""
    content = _content(directory)
    loaded = load_calibration(directory)
    assert loaded.task == "" and loaded.content_hash == content["content_hash"]
    loaded.check_compatible(task="any task")
    assert "detectors" not in content["settings"] and loaded.detectors == declared_detectors(directory) == DETECTORS


def test_old_format_calibrations_are_still_shipped() -> None:
    """The test above must have something to check (the sample sets' calibrations are of the old format)."""
    assert len(WITHOUT_TASK) >= 3


@pytest.mark.parametrize("directory", MODELS_CALIBRATIONS, ids=lambda d: str(d.relative_to(ROOT)))
def test_shipped_model_calibrations_keep_the_promise_by_construction(directory: Path) -> None:
    """Issue #19: the policies' calibrations are split conformal (models and thresholds on disjoint successes)
    with a guaranteed threshold kind, and name the policy's task."""
    content = _content(directory)
    assert content["task"] == directory.parent.name and content["split"]["mode"] == "split"
    assert content["threshold_kind"] in GUARANTEED_KINDS
    assert not set(content["split"]["fit"]) & set(content["split"]["conformal"])


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


def _noise_rollout(rng: np.random.Generator, index: int) -> Rollout:
    """A successful rollout of i.i.d. Gaussian embeddings: every rollout is new, none like another."""
    return Rollout(rollout_id=f"noise-{index}", task="noise", scenario="id",
                   embeddings=rng.normal(size=(6, 32)).astype(np.float32),
                   actions=rng.normal(size=(6, 4, 2, 2)).astype(np.float32), exec_steps=1, success=True)


def test_split_conformal_keeps_the_promise_where_same_data_breaks_it() -> None:
    """Proposition 1 on held-out successes, over seeded trials, with a score model that overfits on purpose
    (an RND-OE predictor trained far past the point of memorising 40 rollouts of noise): fitted and
    calibrated on the same successes its thresholds come out too low; split, the rate stays at delta."""
    from fiper_ros.core.rnd_oe import RNDConfig  # noqa: PLC0415
    from fiper_ros.core.scores import obs_scores  # noqa: PLC0415

    memoriser = RNDConfig(trunk=(64,), head=(64,), out_dim=8, max_epochs=60, lr=1e-2, patience=1000)
    delta, rates = 0.1, {"same": [], "split": []}
    for trial in range(12):
        rng = np.random.default_rng(trial)
        successes = [_noise_rollout(rng, i) for i in range(40)]
        new = [_noise_rollout(rng, 1000 + i) for i in range(100)]
        for split in rates:
            fitted = calibrate(successes, CalibrationSettings(rnd=memoriser, window_obs=1, window_act=1, delta=delta,
                                                              threshold="cp_constant", split=split, seed=trial))
            gamma = fitted.threshold_obs.values[0]
            rates[split].append(np.mean([np.any(obs_scores(fitted.rnd, r.embeddings, fitted.profile) > gamma)
                                         for r in new]))
    split, same = np.array(rates["split"]), np.array(rates["same"])
    # split conformal: E[rate] = 1 - 19/21 = 0.095 for 20 conformal rollouts; allow 3 standard errors
    assert split.mean() <= delta + 3 * split.std(ddof=1) / np.sqrt(split.size), split
    assert same.mean() >= 3 * delta, same  # the broken rule is caught: 0.63 when this test was written


def test_an_infinite_threshold_is_refused_with_the_fewest_successes_that_would_do() -> None:
    rng = np.random.default_rng(3)
    successes = [_noise_rollout(rng, i) for i in range(30)]
    tiny = CalibrationSettings(rnd=TINY_RND, window_obs=1, window_act=1, threshold="cp_constant", delta=0.05)
    # 15 conformal rollouts, 19 needed at delta 0.05 (ceil(20 * 0.95) = 19 <= 19): 38 successes split in half
    with pytest.raises(CalibrationError, match=r"needs at least 19 rollouts, this calibration gives it 15 of 30 "
                                               r"successes; calibrate on at least 38 successful rollouts"):
        calibrate(successes, tiny)
    kept = calibrate(successes, tiny, refuse_infinite=False)
    assert np.isinf(kept.threshold_obs.values).all()


def test_the_split_is_recorded_and_each_kind_states_its_guarantee(calibration: Calibration, tmp_path: Path) -> None:
    from fiper_ros.core.calibration import guarantee  # noqa: PLC0415

    split = calibration.split
    assert split["behind_thresholds"]["obs"] == {"shape": 12, "conformal": 12}  # cp_band: mu, s on the fit part
    assert "Proposition 1" in split["guarantee"] and calibration.false_alarms["held_out_from_models"]
    calibration.save(tmp_path / "saved")
    assert load_calibration(tmp_path / "saved").split == split
    for kind, promise in (("time_varying", "none"), ("cp_scaled", "at most"), ("cp_constant", "at most")):
        assert guarantee(CalibrationSettings(threshold=kind)).startswith(promise), kind
    assert guarantee(CalibrationSettings(split="same")).startswith("not covered by Proposition 1")
    assert guarantee(CalibrationSettings(split="cross")).startswith("about")


def test_or_promises_twice_delta_and_says_how_to_get_delta() -> None:
    """OR alarms when either threshold is exceeded, each on at most delta of new successes: the union bound
    2 delta (the old text promised delta for OR too)."""
    from fiper_ros.core.calibration import guarantee, promised_rate  # noqa: PLC0415

    assert promised_rate(CalibrationSettings(delta=0.05, combine="and")) == 0.05
    assert promised_rate(CalibrationSettings(delta=0.05, combine="or")) == 0.1
    text = guarantee(CalibrationSettings(delta=0.05, combine="or"))
    assert text.startswith("at most 0.1 of new successful rollouts") and "--delta 0.025 for 0.05" in text
    assert guarantee(CalibrationSettings(delta=0.05, combine="and")).startswith("at most 0.05 of new")


def test_reference_profile_calibrates_the_authors_band_on_float32_cells(calibration_rollouts: list[Rollout]) -> None:
    quick = dataclasses.replace(TINY_RND, max_epochs=2)
    settings = CalibrationSettings(rnd=quick, profile="reference", threshold="cp_band", split="same", window_act=3)
    reference = calibrate(calibration_rollouts, settings)
    np.testing.assert_array_equal(reference.cell, np.float32(0.03) * reference.ranges.astype(np.float32))
    successes = successful(calibration_rollouts)  # in the order given: the authors' split takes them so
    curves = [aggregate(act_scores(rollout_positions(r, reference.projection()), reference.cell, reference.profile),
                        "window", 3) for r in successes]
    expected = fit_threshold(curves, settings.threshold_settings())
    np.testing.assert_array_equal(reference.threshold_act.values, expected.values)
    assert (reference.threshold_act.params["m1"], reference.threshold_act.params["m2"]) == (12, 12)  # 1 + 23 // 2
