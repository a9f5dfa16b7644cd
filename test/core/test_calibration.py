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
    Calibration,
    CalibrationError,
    CalibrationMismatch,
    CalibrationSettings,
    calibrate,
    guarantee,
    load_calibration,
    promised_rate,
    upgrade_calibration,
)
from fiper_ros.core.calibration.fit import conformal_count
from fiper_ros.core.calibration_file import CALIBRATION_FILE, declared, declared_detectors
from fiper_ros.core.combination import GroupCurves, fit_joint
from fiper_ros.core.detectors import ACE, DETECTORS, RND_OE
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.core.rollout import Rollout, successful
from fiper_ros.core.scores import act_scores, rollout_positions
from fiper_ros.core.thresholds import GUARANTEED_KINDS, fit_threshold
from fiper_ros.core.window import aggregate

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = sorted([*ROOT.glob("models/*/calibration*"), *ROOT.glob("bags/*/calibration")])
FORMAT2 = ROOT / "test" / "data" / "calibration_format2"


def test_fitted_fields(calibration: Calibration, calibration_rollouts: list[Rollout]) -> None:
    assert calibration.num_rollouts == 24  # the failed rollout is not used
    layout = calibration.layout
    assert (layout.embedding_dim, layout.action_dim, layout.horizon) == (EMBEDDING_DIM, ACTION_DIM, HORIZON)
    # split conformal (the default): R_d from the rollouts that fitted the models, none of the conformal set
    split = calibration.split
    assert split["mode"] == "split" and len(split["fit"]) == len(split["conformal"]) == 12
    assert not set(split["fit"]) & set(split["conformal"])
    fitted = [r.actions[..., :3] for r in calibration_rollouts if r.success and str(r.rollout_id) in split["fit"]]
    ace = calibration.scorer(ACE)
    assert np.allclose(ace.ranges, action_ranges(fitted))
    assert np.allclose(ace.cell, 0.03 * ace.ranges)
    longest = max(r.length for r in calibration_rollouts if r.success)
    assert calibration.threshold(RND_OE).values.shape == (longest,)
    assert calibration.threshold(ACE).kind == "cp_band" and np.all(np.isfinite(calibration.threshold(ACE).values))


def test_save_load_round_trip(calibration: Calibration, tmp_path: Path) -> None:
    path = calibration.save(tmp_path)
    content = yaml.safe_load(path.read_text())
    for key in ("format_version", "settings", "layout", "guarantee", "tasks", "false_alarm_estimate", "content_hash"):
        assert key in content
    assert content["format_version"] == 3 and list(content["tasks"]) == ["synthetic"]
    loaded = load_calibration(tmp_path)
    assert loaded.content_hash == calibration.content_hash == content["content_hash"]
    assert loaded.settings == calibration.settings and loaded.layout == calibration.layout
    for detector in DETECTORS:
        assert np.array_equal(loaded.threshold(detector).values, calibration.threshold(detector).values)
    assert np.array_equal(loaded.scorer(ACE).ranges, calibration.scorer(ACE).ranges)


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
    layout = fitting.layout
    with pytest.raises(CalibrationMismatch) as error:
        load_calibration(directory).check_compatible(
            embedding_dim=layout.embedding_dim, action_dim=layout.action_dim, horizon=layout.horizon,
            exec_steps=layout.exec_steps, action_space=layout.action_space, task=fitting.named_tasks[0])
    assert str(error.value).startswith(expected), str(error.value)


def test_rollouts_of_several_tasks_are_calibrated_each_with_its_own_models_and_shapes(
        calibration_rollouts: list[Rollout], settings: CalibrationSettings) -> None:
    """Each task its own models, split and thresholds; a rollout of a task the calibration never saw cannot be
    judged (a mismatch naming the tasks), one without a task neither when there are several."""
    rng = np.random.default_rng(11)
    other = [dataclasses.replace(make_rollout(rng, 100 + i), task="other", rollout_id=f"other-{i}") for i in range(12)]
    both = calibrate([*calibration_rollouts, *other], dataclasses.replace(settings, delta=0.3))
    assert list(both.tasks) == ["other", "synthetic"] and both.named_tasks == ("other", "synthetic")
    assert both.tasks["other"].num_rollouts == 12 and both.tasks["synthetic"].num_rollouts == 24
    assert both.scorer(RND_OE, "other") is not both.scorer(RND_OE, "synthetic")
    assert set(both.tasks["other"].split["fit"]) <= {f"other-{i}" for i in range(12)}
    with pytest.raises(CalibrationMismatch, match=r"task: expected other or synthetic, got third"):
        both.part("third")
    with pytest.raises(CalibrationMismatch, match=r"task: expected other or synthetic, got \(none\)"):
        both.part("")


def test_a_calibration_without_a_task_judges_any_and_one_task_judges_rollouts_without_one(
        calibration: Calibration) -> None:
    assert calibration.named_tasks == ("synthetic",)
    assert calibration.part("") is calibration.part("synthetic")  # a caller that does not know the task
    with pytest.raises(CalibrationMismatch, match="task: expected synthetic, got other"):
        calibration.check_compatible(task="other")
    anonymous = dataclasses.replace(calibration, tasks={"": calibration.part("synthetic")})
    assert anonymous.part("any task") is calibration.part("synthetic")


def _content(directory: Path) -> dict[str, Any]:
    return yaml.safe_load((directory / CALIBRATION_FILE).read_text())


@pytest.mark.parametrize("directory", SHIPPED, ids=lambda d: str(d.relative_to(ROOT)))
def test_shipped_calibrations_are_of_the_current_format_and_load(directory: Path) -> None:
    content = _content(directory)
    loaded = load_calibration(directory)
    assert content["format_version"] == 3 and loaded.content_hash == content["content_hash"]
    assert loaded.detectors == declared_detectors(directory) == tuple(content["settings"]["detectors"])


def test_a_format_2_calibration_loads_as_it_is_and_upgrades_to_the_same_thresholds_and_weights(tmp_path: Path) -> None:
    """Written before any other detector existed: read as FIPER's pair (its windows, thresholds, ranges and
    weights), its own content hash checked; ``--upgrade`` writes the same calibration in format 3, which scores a
    rollout identically."""
    old = load_calibration(FORMAT2)
    assert old.detectors == DETECTORS and old.named_tasks == () and old.settings.windows == {ACE: 50}
    assert old.settings.window_of(RND_OE) == 8 and old.settings.combine == "and"
    assert declared(FORMAT2).detectors == DETECTORS
    upgraded = upgrade_calibration(FORMAT2)
    upgraded.save(tmp_path / "new")
    new = load_calibration(tmp_path / "new")
    assert _content(tmp_path / "new")["format_version"] == 3
    for detector in DETECTORS:
        assert np.array_equal(new.threshold(detector).values, old.threshold(detector).values)
    assert new.scorer(RND_OE).digest() == old.scorer(RND_OE).digest()
    rng = np.random.default_rng(0)
    rollout = Rollout("r", "", "id", rng.normal(size=(30, old.layout.embedding_dim)),
                      rng.normal(size=(30, 32, old.layout.horizon, old.layout.action_dim)), old.layout.exec_steps, None)
    a, b = predict_rollout(rollout, old), predict_rollout(rollout, new)
    for detector in DETECTORS:
        assert np.array_equal(a.detectors[detector].windowed, b.detectors[detector].windowed)
    edited = tmp_path / "edited"
    shutil.copytree(FORMAT2, edited)
    text = (edited / CALIBRATION_FILE).read_text().replace("window_obs: 8", "window_obs: 9")
    (edited / CALIBRATION_FILE).write_text(text)
    with pytest.raises(CalibrationError, match="content hash mismatch"):
        load_calibration(edited)


@pytest.mark.parametrize("directory", sorted(ROOT.glob("models/*/calibration*")), ids=lambda d: str(d.relative_to(ROOT)))
def test_shipped_model_calibrations_keep_the_promise_by_construction(directory: Path) -> None:
    """The policies' calibrations are split conformal (models and thresholds on disjoint successes) with a
    guaranteed threshold kind."""
    content = _content(directory)
    assert content["settings"]["threshold"] in GUARANTEED_KINDS
    for part in content["tasks"].values():
        assert part["split"]["mode"] == "split" and not set(part["split"]["fit"]) & set(part["split"]["conformal"])


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
    with pytest.raises(CalibrationError, match="at least 4 successful rollouts of task 'synthetic', got 3"):
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
    assert np.allclose(reference.scorer(ACE).ranges, action_ranges([r.actions[..., :3] for r in calibration_rollouts]))
    assert reference.threshold(RND_OE).extension == "mean"


def _noise_rollout(rng: np.random.Generator, index: int) -> Rollout:
    """A successful rollout of i.i.d. Gaussian embeddings: every rollout is new, none like another."""
    return Rollout(rollout_id=f"noise-{index}", task="noise", scenario="id",
                   embeddings=rng.normal(size=(6, 32)).astype(np.float32),
                   actions=rng.normal(size=(6, 4, 2, 2)).astype(np.float32), exec_steps=1, success=True)


def test_split_conformal_keeps_the_promise_where_same_data_breaks_it() -> None:
    """Proposition 1 on held-out successes, over seeded trials, with a score model that overfits on purpose
    (an RND-OE predictor trained far past the point of memorising 40 rollouts of noise): fitted and
    calibrated on the same successes its thresholds come out too low; split, the rate stays at delta."""
    from fiper_ros.core.rnd_oe import RNDConfig

    memoriser = RNDConfig(trunk=(64,), head=(64,), out_dim=8, max_epochs=60, lr=1e-2, patience=1000)
    delta, rates = 0.1, {"same": [], "split": []}
    for trial in range(12):
        rng = np.random.default_rng(trial)
        successes = [_noise_rollout(rng, i) for i in range(40)]
        new = [_noise_rollout(rng, 1000 + i) for i in range(100)]
        for split in rates:
            fitted = calibrate(successes, CalibrationSettings(rnd=memoriser, window=1, delta=delta,
                                                              threshold="cp_constant", split=split, seed=trial))
            gamma = fitted.threshold(RND_OE).values[0]
            scorer = fitted.scorer(RND_OE)
            rates[split].append(np.mean([np.any(scorer.scores(r) > gamma) for r in new]))
    split, same = np.array(rates["split"]), np.array(rates["same"])
    # split conformal: E[rate] = 1 - 19/21 = 0.095 for 20 conformal rollouts; allow 3 standard errors
    assert split.mean() <= delta + 3 * split.std(ddof=1) / np.sqrt(split.size), split
    assert same.mean() >= 3 * delta, same  # the broken rule is caught: 0.63 when this test was written


def test_an_infinite_threshold_is_refused_with_the_fewest_successes_that_would_do() -> None:
    rng = np.random.default_rng(3)
    successes = [_noise_rollout(rng, i) for i in range(30)]
    tiny = CalibrationSettings(rnd=TINY_RND, window=1, threshold="cp_constant", delta=0.05)
    # 15 conformal rollouts, 19 needed at delta 0.05 (ceil(20 * 0.95) = 19 <= 19): 38 successes split in half
    with pytest.raises(CalibrationError, match=r"needs at least 19 rollouts, this calibration gives it 15 of 30 "
                                               r"successes; calibrate on at least 38 successful rollouts"):
        calibrate(successes, tiny)
    kept = calibrate(successes, tiny, refuse_infinite=False)
    assert np.isinf(kept.threshold(RND_OE).values).all()


def test_the_split_is_recorded_and_each_kind_states_its_guarantee(calibration: Calibration, tmp_path: Path) -> None:
    part = calibration.part("synthetic")
    assert part.split["behind_thresholds"][RND_OE] == {"shape": 12, "conformal": 12}  # cp_band: mu, s on the fit part
    assert "Proposition 1" in calibration.guarantee and calibration.false_alarms["held_out_from_models"]
    calibration.save(tmp_path / "saved")
    assert load_calibration(tmp_path / "saved").split == calibration.split
    for kind, promise in (("time_varying", "none"), ("cp_scaled", "at most"), ("cp_constant", "at most")):
        assert guarantee(CalibrationSettings(threshold=kind)).startswith(promise), kind
    assert guarantee(CalibrationSettings(split="same")).startswith("not covered by Proposition 1")
    assert guarantee(CalibrationSettings(split="cross")).startswith("about")


def test_or_promises_n_times_delta_and_a_joint_combine_delta() -> None:
    """OR alarms when any of N thresholds is exceeded, each on at most delta of new successes: the union bound
    N delta; a joint combine (one conformal factor) promises delta however many detectors vote."""
    assert promised_rate(CalibrationSettings(delta=0.05, combine="and")) == 0.05
    assert promised_rate(CalibrationSettings(delta=0.05, combine="or")) == 0.1
    three = ("rnd_oe", "progress", "elapsed")
    assert promised_rate(CalibrationSettings(delta=0.05, combine="or", detectors=three)) == pytest.approx(0.15)
    assert promised_rate(CalibrationSettings(delta=0.05, combine="max", detectors=three)) == 0.05
    text = guarantee(CalibrationSettings(delta=0.05, combine="or"))
    assert text.startswith("at most 0.1 of new successful rollouts") and "--delta 0.025 for 0.05" in text
    assert "combine max" in text
    assert guarantee(CalibrationSettings(delta=0.05, combine="and")).startswith("at most 0.05 of new")
    joint = guarantee(CalibrationSettings(delta=0.05, combine="kth:2", detectors=three))
    assert joint.startswith("at most 0.05 of new") and "kth:2 of 3 detectors under one conformal threshold" in joint


def test_reference_profile_calibrates_the_authors_band_on_float32_cells(calibration_rollouts: list[Rollout]) -> None:
    quick = dataclasses.replace(TINY_RND, max_epochs=2)
    settings = CalibrationSettings(rnd=quick, profile="reference", threshold="cp_band", split="same", windows={ACE: 3})
    reference = calibrate(calibration_rollouts, settings)
    ace = reference.scorer(ACE)
    np.testing.assert_array_equal(ace.cell, np.float32(0.03) * ace.ranges.astype(np.float32))
    successes = successful(calibration_rollouts)  # in the order given: the authors' split takes them so
    curves = [aggregate(act_scores(rollout_positions(r, ace.projection(None)), ace.cell, reference.profile),
                        "window", 3) for r in successes]
    expected = fit_threshold(curves, settings.threshold_settings())
    np.testing.assert_array_equal(reference.threshold(ACE).values, expected.values)
    assert (reference.threshold(ACE).params["m1"], reference.threshold(ACE).params["m2"]) == (12, 12)  # 1 + 23 // 2


# -- any detectors, one conformal threshold -----------------------------------------------------------------------
THREE = (RND_OE, "progress", "elapsed")


def test_a_joint_combine_is_the_core_combination_of_the_detectors_curves(calibration_rollouts: list[Rollout]) -> None:
    """max over RND-OE, progress and the elapsed time: every detector's threshold is its shape times the one
    conformal factor fit_joint finds on the split's curves (the elapsed time always CP scaled, cumulative)."""
    settings = CalibrationSettings(rnd=TINY_RND, detectors=THREE, combine="max", threshold="cp_band", delta=0.2,
                                   window=3)
    fitted = calibrate(calibration_rollouts, settings)
    part, successes = fitted.part("synthetic"), successful(calibration_rollouts)
    index = {str(r.rollout_id): r for r in successes}

    def curves(ids: list[str]) -> dict[str, list[np.ndarray]]:
        return {d: [aggregate(fitted.scorer(d).scores(index[i]), settings.aggregation_of(d), settings.window_of(d))
                    for i in ids] for d in THREE}

    group = GroupCurves(curves(part.split["fit"]), curves(part.split["conformal"]))
    expected = fit_joint({"synthetic": group}, THREE, {d: settings.shape_of(d) for d in THREE}, 1,
                         settings.threshold_settings())
    for detector in THREE:
        np.testing.assert_array_equal(part.detectors[detector].threshold.values,
                                      expected.thresholds["synthetic"][detector].values)
    assert settings.aggregation_of("elapsed") == "cumulative" and settings.shape_of("elapsed") == "cp_scaled"
    assert fitted.joint == {"votes": 1}
    assert declared(_saved(fitted)).combine == "max"


@pytest.mark.parametrize("equalise", ["quantile", "tail"])
def test_an_equalised_joint_combine_is_the_core_one_and_its_file_records_the_equalisers(
        calibration_rollouts: list[Rollout], tmp_path: Path, equalise: str) -> None:
    """max over RND-OE, progress and the elapsed time with equalised tails: the thresholds are fit_joint's on the
    split's curves (the equalisers from the fit part's), the file names each detector's equaliser and factor in
    plain YAML, and a loaded calibration judges as the fitted one."""
    settings = CalibrationSettings(rnd=TINY_RND, detectors=THREE, combine="max", threshold="cp_band", delta=0.2,
                                   window=3, equalise=equalise, equalise_level=0.8)
    fitted = calibrate(calibration_rollouts, settings)
    part = fitted.part("synthetic")
    index = {str(r.rollout_id): r for r in successful(calibration_rollouts)}

    def curves(ids: list[str]) -> dict[str, list[np.ndarray]]:
        return {d: [aggregate(fitted.scorer(d).scores(index[i]), settings.aggregation_of(d), settings.window_of(d))
                    for i in ids] for d in THREE}

    group = GroupCurves(curves(part.split["fit"]), curves(part.split["conformal"]))
    expected = fit_joint({"synthetic": group}, THREE, {d: settings.shape_of(d) for d in THREE}, 1,
                         settings.threshold_settings(), equalise, 0.8)
    for detector in THREE:
        threshold = part.detectors[detector].threshold
        np.testing.assert_array_equal(threshold.values, expected.thresholds["synthetic"][detector].values)
        assert threshold.params["equaliser"] == expected.equalisers[detector].to_dict()
        assert threshold.params["factor"] == expected.equalisers[detector].inverse(expected.k)
    assert fitted.joint == {"votes": 1, "equalise": equalise}
    assert ("equalise_level" in settings.to_dict()) == (equalise == "quantile")
    path = fitted.save(tmp_path)
    written = yaml.safe_load(path.read_text())
    assert written["settings"]["equalise"] == equalise
    assert written["tasks"]["synthetic"]["detectors"][RND_OE]["threshold"]["params"]["equaliser"]["kind"] == equalise
    loaded = load_calibration(tmp_path)
    assert loaded.content_hash == fitted.content_hash and loaded.settings == settings
    for rollout in calibration_rollouts[:3]:
        assert np.array_equal(predict_rollout(rollout, fitted).alarms, predict_rollout(rollout, loaded).alarms)


def test_a_detector_whose_tail_cannot_be_equalised_is_refused_by_name() -> None:
    """The elapsed time over successes of one length has one fit maximum: no tail map, a CalibrationError naming it."""
    rng = np.random.default_rng(9)
    rollouts = [make_rollout(rng, i, length=30) for i in range(12)]
    settings = CalibrationSettings(rnd=TINY_RND, detectors=(RND_OE, "elapsed"), combine="max", delta=0.2,
                                   equalise="tail")
    with pytest.raises(CalibrationError, match=r"^detector 'elapsed': tail equalisation needs at least 2 distinct "
                                               r"maxima in the fit part, got 1 \(of 6\)$"):
        calibrate(rollouts, settings)
    assert calibrate(rollouts, dataclasses.replace(settings, equalise="quantile")).joint["equalise"] == "quantile"


def test_settings_without_equalising_write_what_they_wrote_before() -> None:
    """The equalisation is written only when set: a calibration without it has the content (and hash) it had."""
    for settings in (CalibrationSettings(), CalibrationSettings(combine="max", detectors=THREE)):
        assert settings.equalise == "none"
        assert not {"equalise", "equalise_level"} & set(settings.to_dict())
        assert CalibrationSettings.from_dict(settings.to_dict()) == settings


def _saved(calibration: Calibration) -> Path:
    import tempfile

    directory = Path(tempfile.mkdtemp()) / "calibration"
    calibration.save(directory)
    return directory


def test_a_calibration_of_any_detectors_round_trips(calibration_rollouts: list[Rollout], tmp_path: Path) -> None:
    settings = CalibrationSettings(rnd=TINY_RND, detectors=(*THREE, "consistency", "pca_kmeans"), combine="kth:2",
                                   threshold="cp_scaled", delta=0.2, windows={"progress": 5})
    fitted = calibrate(calibration_rollouts, settings)
    fitted.save(tmp_path)
    names = sorted(p.name for p in tmp_path.iterdir())
    assert names == ["calibration.yaml", "consistency.json", "consistency.npz", "pca_kmeans.json", "pca_kmeans.npz",
                     "progress.json", "progress.npz", "rnd_oe.json", "rnd_oe.npz"]
    loaded = load_calibration(tmp_path)
    assert loaded.content_hash == fitted.content_hash and loaded.settings.votes == 2
    rollout = calibration_rollouts[0]
    a, b = predict_rollout(rollout, fitted), predict_rollout(rollout, loaded)
    assert np.array_equal(a.alarms, b.alarms)
    for detector in settings.detectors:
        assert np.array_equal(a.detectors[detector].windowed, b.detectors[detector].windowed)
    (tmp_path / "progress.npz").unlink()
    with pytest.raises(CalibrationError, match=r"progress model file missing: .*progress\.npz"):
        load_calibration(tmp_path)


def test_pooled_thresholds_share_one_factor_over_the_tasks(calibration_rollouts: list[Rollout]) -> None:
    """Two tasks of 12 successes (6 conformal each) cannot serve delta 0.1 apiece (9 needed): refused with the hint
    to pool; pooled, one conformal factor over their 12 conformal rollouts serves it."""
    rng = np.random.default_rng(5)
    rollouts = [dataclasses.replace(make_rollout(rng, i), task=task, rollout_id=f"{task}-{i}")
                for task in ("a", "b") for i in range(12)]
    settings = CalibrationSettings(rnd=TINY_RND, detectors=(RND_OE, "elapsed"), combine="max", threshold="cp_band",
                                   delta=0.1)
    with pytest.raises(CalibrationError, match=r"or pool the tasks \(--pool\)"):
        calibrate(rollouts, settings)
    pooled = calibrate(rollouts, dataclasses.replace(settings, pooled=True))
    assert pooled.joint["m"] == 12 and pooled.joint["conformal"] == {"a": 6, "b": 6}
    k = pooled.joint["k"]
    for task in ("a", "b"):
        assert pooled.threshold(RND_OE, task).params["k"] == k
    assert "pooled over the tasks" in pooled.guarantee


def test_settings_refuse_what_cannot_be_calibrated() -> None:
    with pytest.raises(CalibrationError, match=r"detector 'stac' cannot be calibrated"):
        CalibrationSettings(detectors=("rnd_oe", "stac"))
    with pytest.raises(CalibrationError, match=r"a joint combine normalises each detector by its shape: threshold "
                                               r"one of cp_band, cp_scaled, cp_constant, not time_varying"):
        CalibrationSettings(combine="max", threshold="time_varying")
    with pytest.raises(CalibrationError, match=r"combine kth:3 needs at least 3 detectors, got 2"):
        CalibrationSettings(combine="kth:3")
    with pytest.raises(CalibrationError, match=r"^equalise tail applies to a joint combine \(max, kth:K\), not and$"):
        CalibrationSettings(equalise="tail")
    with pytest.raises(CalibrationError, match=r"^unknown equalisation 'median'; expected one of none, quantile, "
                                               r"tail$"):
        CalibrationSettings(combine="max", equalise="median")
    with pytest.raises(CalibrationError, match=r"^equalise quantile divides by a positive quantile of the fit part's "
                                               r"maxima, which the cp_constant shape centres on 0: equalise tail "
                                               r"instead$"):
        CalibrationSettings(combine="max", threshold="cp_constant", equalise="quantile")
    CalibrationSettings(combine="max", threshold="cp_constant", equalise="tail")
    with pytest.raises(CalibrationError, match=r"^the equalisation level must be in \(0, 1\), got 0\.0$"):
        CalibrationSettings(combine="max", equalise="quantile", equalise_level=0.0)
    with pytest.raises(CalibrationError, match=r"windows of undeclared detectors: progress"):
        CalibrationSettings(windows={"progress": 3})
    assert CalibrationSettings(detectors=("elapsed", "rnd_oe")).detectors == ("rnd_oe", "elapsed")


def test_a_normalised_fit_without_a_fit_part_counts_only_its_conformal_half() -> None:
    """Without a fit part (split ``same``), a joint combine or pooled thresholds split the curves into shape and
    conformal halves whatever the shape kind: CP constant's count is the half's, as the band's (the count that
    says whether a delta is reachable and how many successes would do)."""
    kwargs: dict[str, Any] = {"detectors": (RND_OE, ACE), "split": "same"}
    assert conformal_count(40, "same", CalibrationSettings(**kwargs, combine="max", threshold="cp_constant")) == 20
    assert conformal_count(40, "same", CalibrationSettings(**kwargs, pooled=True, threshold="cp_constant")) == 20
    assert conformal_count(40, "same", CalibrationSettings(**kwargs, combine="max", threshold="cp_band")) == 20
    assert conformal_count(40, "same", CalibrationSettings(**kwargs, combine="and", threshold="cp_constant")) == 40
