"""The protocols that choose per task: leave-one-task-out (each task's configuration chosen without its labels,
reported on it), clean-task (each task's chosen on its own validation half alone, reported on its other half) and
paper-task (each task's chosen and reported on its own test rollouts: the per-task ceiling)."""

from __future__ import annotations

import json
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import EngineSettings, run_evaluation
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.protocol import (METRICS, run_clean_task, run_loto, run_paper_task, run_protocol,
                                          validation_split)
from fiper_ros.evaluation.report import write_reports
from fiper_ros.evaluation.sweep import Group, SweepSettings
from fiper_ros.evaluation.synthetic import make_task

GROUPS = [Group("rnd_oe", "1", "cp_band"), Group("rnd_oe", "2", "cp_band")]
TWA = METRICS.index("twa")


def _metrics(twa: list[list[float]]) -> np.ndarray:
    """``[tasks, 1 seed, groups, 1 delta, 5]`` with the given TWA per task and group (other metrics 0)."""
    out = np.zeros((len(twa), 1, len(twa[0]), 1, len(METRICS)))
    out[:, 0, :, 0, TWA] = twa
    return out


# TWA of groups (w 1, w 2) on tasks a, b, c. Leaving a out: b and c give w 1 0.40, w 2 0.65 -> w 2; leaving b out:
# a and c give 0.75, 0.30 -> w 1; leaving c out: a and b give 0.55, 0.45 -> w 1. Over all three (what a protocol
# that read a's own labels would use) w 1 wins for a: 0.567 against 0.467.
HAND = [[0.9, 0.1], [0.2, 0.8], [0.6, 0.5]]


def test_loto_chooses_each_task_from_the_other_tasks_by_hand() -> None:
    metrics = _metrics(HAND)
    result = run_loto(GROUPS, metrics, ["rnd_oe"])
    chosen = result.selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["2", "1", "1"]
    np.testing.assert_array_equal(chosen.values[:, 0, TWA], [0.1, 0.2, 0.6])  # each task at its own choice
    assert result.selection_twa["rnd_oe"] == pytest.approx((0.65 + 0.75 + 0.55) / 3)
    paper = run_protocol("paper", GROUPS, metrics, metrics, ["rnd_oe"], 1, "cp_band")
    assert paper.selected["rnd_oe"].group.window == "1"  # reading a's labels would give a w 1


def test_a_tasks_own_labels_never_change_its_choice() -> None:
    # flip every metric of the held-out task (its labels flipped): its choice stays, the others' may move
    for held_out in range(3):
        flipped = [row if t != held_out else [1.0 - v for v in row] for t, row in enumerate(HAND)]
        before = run_loto(GROUPS, _metrics(HAND), ["rnd_oe"]).selected["rnd_oe"]
        after = run_loto(GROUPS, _metrics(flipped), ["rnd_oe"]).selected["rnd_oe"]
        assert after.task_groups[held_out] == before.task_groups[held_out]


def test_a_configuration_infinite_on_the_reported_task_is_not_chosen_for_it() -> None:
    infinite = np.zeros((3, 1, 2, 1), dtype=bool)
    infinite[0, 0, 1] = True  # w 2 is +inf on a (its calibration successes): a gets w 1 although b, c prefer w 2
    chosen = run_loto(GROUPS, _metrics(HAND), ["rnd_oe"], infinite=infinite).selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["1", "1", "1"]


def test_loto_with_one_task_is_refused() -> None:
    with pytest.raises(ValueError, match="two tasks or more"):
        run_loto(GROUPS, _metrics(HAND[:1]), ["rnd_oe"])


def test_loto_with_one_task_is_a_one_line_refusal(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["evaluate", "--synthetic", "sorting", "--synthetic-scale", "0.25", "--synthetic-test", "8", "--tiny",
            "--windows", "1-5", "--protocol", "paper,loto", "--out", str(tmp_path / "out"), "--no-cache"]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err == ("fiper evaluate: --protocol loto leaves one task out at a time: it needs two tasks or more, got 1 "
                   "(sorting)\n")
    assert not (tmp_path / "out").exists()


def _datasets() -> list[Dataset]:
    out = []
    for seed, task in enumerate(("sorting", "push_t", "stacking")):
        rollouts = make_task(task, seed=seed, calibration=12, test=16, scale=0.25)
        out.append(Dataset(task, rollouts.calibration, rollouts.test))
    return out


def _settings() -> EngineSettings:
    return EngineSettings(methods=("elapsed", "rnd_oe", "stac"), sweep=SweepSettings(
        windows=(1, 2, 3), deltas=(0.1, 0.2), kinds=("cp_band", "cp_constant"), max_pool=()),
        method_settings=MethodSettings.tiny(), protocols=("paper", "loto"), default_window=1, progress=False)


def test_flipping_the_reported_tasks_labels_leaves_its_choice_and_the_report_names_the_protocol(tmp_path: Path) -> None:
    datasets = _datasets()
    flipped = [datasets[0], replace(datasets[1], test=[replace(r, success=not r.success) for r in datasets[1].test]),
               datasets[2]]
    settings = _settings()
    before = run_evaluation(datasets, settings)
    after = run_evaluation(flipped, settings)
    for method in ("rnd_oe", "stac"):
        assert (after.protocols["loto"].selected[method].task_groups[1]
                == before.protocols["loto"].selected[method].task_groups[1])
    markdown, js = write_reports(before, tmp_path, [])
    text = markdown.read_text()
    assert "## Table 1: failure prediction, leave-one-task-out protocol" in text
    assert "## Early detection (threshold-free), loto protocol" in text and "threshold-free" in text
    document = json.loads(js.read_text())
    chosen = document["protocols"]["loto"]["selected"]["rnd_oe"]
    assert chosen["config"] == "per task"
    assert {t: chosen["tasks"][t]["config"]["window"] for t in ("sorting", "push_t", "stacking")} == {
        d.task: g.window for d, g in zip(datasets, before.protocols["loto"].selected["rnd_oe"].task_groups)}
    early = chosen["early_detection"]
    assert set(early["tasks"]) == {"sorting", "push_t", "stacking"} and early["pooled"]["auroc"]["mean"] is not None


def test_an_auroc_with_an_empty_class_is_a_visible_null(tmp_path: Path) -> None:
    datasets = _datasets()
    datasets[1] = replace(datasets[1], test=[r for r in datasets[1].test if r.success])  # push_t: no failures
    result = run_evaluation(datasets, _settings())
    early = result.early["loto"]["rnd_oe"]
    assert np.isnan(early.auroc[1]).all() and not np.isnan(early.auroc[0]).any()
    assert not np.isnan(early.pooled_auroc).any()  # the pooled AUROC has both classes from the other tasks
    markdown, js = write_reports(result, tmp_path, [])
    row = next(line for line in markdown.read_text().splitlines() if line.startswith("| RND-OE | chosen per task"))
    assert row.split(" | ")[3] == "null (no failures)"
    push_t = json.loads(js.read_text())["protocols"]["loto"]["selected"]["rnd_oe"]["early_detection"]["tasks"]["push_t"]
    assert push_t["auroc"]["mean"] is None and push_t["auroc"]["undefined"] == "null (no failures)"


# Validation-half TWA of (w 1, w 2) on tasks a, b, c: a prefers w 1, b w 2, c w 1. Over all three (the clean
# protocol's one choice for every task) w 1 wins: mean 0.567 against 0.467. Report halves: other numbers.
VALIDATION = [[0.9, 0.1], [0.2, 0.8], [0.6, 0.5]]
REPORT = [[0.7, 0.3], [0.4, 0.6], [0.55, 0.45]]


def test_each_task_is_chosen_on_its_own_validation_half_by_hand() -> None:
    result = run_clean_task(GROUPS, _metrics(VALIDATION), _metrics(REPORT), ["rnd_oe"])
    chosen = result.selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["1", "2", "1"]
    np.testing.assert_array_equal(chosen.values[:, 0, TWA], [0.7, 0.6, 0.55])  # each task's report half, its choice
    assert result.selection_twa["rnd_oe"] == pytest.approx((0.9 + 0.8 + 0.6) / 3)
    assert result.protocol == "clean-task" and not result.default
    clean = run_protocol("clean", GROUPS, _metrics(VALIDATION), _metrics(REPORT), ["rnd_oe"], 1, "cp_band")
    assert clean.selected["rnd_oe"].group.window == "1"  # one choice for all: b gets w 1 (0.4, not 0.6)


def test_neither_the_report_half_nor_another_tasks_labels_change_a_choice() -> None:
    before = run_clean_task(GROUPS, _metrics(VALIDATION), _metrics(REPORT), ["rnd_oe"]).selected["rnd_oe"]
    flipped_report = [[1.0 - v for v in row] for row in REPORT]
    after = run_clean_task(GROUPS, _metrics(VALIDATION), _metrics(flipped_report), ["rnd_oe"]).selected["rnd_oe"]
    assert after.task_groups == before.task_groups
    for task in range(3):  # flip every other task's validation half: this task's choice stays
        flipped = [row if t == task else [1.0 - v for v in row] for t, row in enumerate(VALIDATION)]
        moved = run_clean_task(GROUPS, _metrics(flipped), _metrics(REPORT), ["rnd_oe"]).selected["rnd_oe"]
        assert moved.task_groups[task] == before.task_groups[task]


def test_a_configuration_infinite_on_a_task_is_not_chosen_for_it() -> None:
    infinite = np.zeros((3, 1, 2, 1), dtype=bool)
    infinite[1, 0, 1] = True  # w 2 is +inf on b: b gets w 1 although its validation half prefers w 2
    validation, report = _metrics(VALIDATION), _metrics(REPORT)
    validation[1, 0, 1], report[1, 0, 1] = np.nan, np.nan  # the sweep leaves +inf cells without metrics
    chosen = run_clean_task(GROUPS, validation, report, ["rnd_oe"], infinite=infinite).selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["1", "1", "1"]


def test_flipping_the_report_halfs_labels_leaves_every_choice_and_the_report_names_the_protocol(tmp_path: Path) -> None:
    datasets = _datasets()
    settings = replace(_settings(), protocols=("clean-task",))
    reports = [validation_split(d.failed, settings.split_seed)[1] for d in datasets]
    # swap the outcome of every report-half rollout within its class's count: the halves stay (they are drawn per
    # outcome class), each report rollout's label flips in a way that keeps the split: exchange arrays instead
    flipped = []
    for d, report in zip(datasets, reports):
        test = list(d.test)
        failures = [i for i in report if not test[i].success]
        successes = [i for i in report if test[i].success]
        for a, b in zip(failures, successes):  # a report failure and a report success trade their scores
            test[a], test[b] = replace(test[b], success=test[a].success, scenario=test[a].scenario), \
                replace(test[a], success=test[b].success, scenario=test[b].scenario)
        flipped.append(replace(d, test=test))
    before = run_evaluation(datasets, settings)
    after = run_evaluation(flipped, settings)
    for method in ("rnd_oe", "stac"):
        assert after.protocols["clean-task"].selected[method].task_groups == \
            before.protocols["clean-task"].selected[method].task_groups
    markdown, js = write_reports(before, tmp_path, [])
    text = markdown.read_text()
    assert "## Table 1: failure prediction, clean protocol chosen per task" in text
    assert "no other task's labels and none of its report half enter the choice" in text
    assert "## Early detection (threshold-free), clean-task protocol" in text
    chosen = json.loads(js.read_text())["protocols"]["clean-task"]["selected"]["rnd_oe"]
    assert chosen["config"] == "per task"
    # each task's promise is its own configuration's: the top level names none (not the first task's)
    assert chosen["guarantee"] == "per task"
    assert {chosen["tasks"][t]["guarantee"] for t in ("sorting", "push_t", "stacking")} <= {"≤ δ", "none (per-step quantile)"}
    assert {t: chosen["tasks"][t]["config"]["window"] for t in ("sorting", "push_t", "stacking")} == {
        d.task: g.window for d, g in zip(datasets, before.protocols["clean-task"].selected["rnd_oe"].task_groups)}


def test_paper_task_chooses_each_task_on_its_own_rollouts_by_hand() -> None:
    # HAND: a prefers w 1 (0.9), b w 2 (0.8), c w 1 (0.6); each reported where it was chosen
    result = run_paper_task(GROUPS, _metrics(HAND), ["rnd_oe"])
    chosen = result.selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["1", "2", "1"]
    np.testing.assert_array_equal(chosen.values[:, 0, TWA], [0.9, 0.8, 0.6])
    assert result.selection_twa["rnd_oe"] == pytest.approx((0.9 + 0.8 + 0.6) / 3)
    assert result.protocol == "paper-task" and not result.default
    infinite = np.zeros((3, 1, 2, 1), dtype=bool)
    infinite[1, 0, 1] = True  # w 2 is +inf on b: b's ceiling is w 1's 0.2, not a NaN cell
    metrics = _metrics(HAND)
    metrics[1, 0, 1] = np.nan
    chosen = run_paper_task(GROUPS, metrics, ["rnd_oe"], infinite=infinite).selected["rnd_oe"]
    assert [g.window for g in chosen.task_groups] == ["1", "1", "1"]
    np.testing.assert_array_equal(chosen.values[:, 0, TWA], [0.9, 0.2, 0.6])


def test_paper_task_is_a_ceiling_of_the_protocols_that_report_on_all_rollouts() -> None:
    # random metrics (2 seeds, 3 deltas, some +inf cells): per method and task, the paper-task figure is at least what
    # the paper protocol (one choice for all tasks) and LOTO (chosen on the other tasks) report there, and equals the
    # best any selectable configuration of the method has on that task
    groups = [Group(m, str(w), k) for m in ("rnd_oe", "stac") for w in (1, 2, 3) for k in ("cp_band", "cp_constant")]
    for trial in range(200):
        rng = np.random.default_rng(trial)
        metrics = rng.uniform(size=(4, 2, len(groups), 3, len(METRICS)))
        infinite = rng.uniform(size=metrics.shape[:-1]) < 0.1
        metrics[infinite] = np.nan
        ceiling = run_paper_task(groups, metrics, ["rnd_oe", "stac"], infinite=infinite)
        paper = run_protocol("paper", groups, metrics, metrics, ["rnd_oe", "stac"], 1, "cp_band", infinite=infinite)
        loto = run_loto(groups, metrics, ["rnd_oe", "stac"], infinite=infinite)
        usable = ~infinite.all(axis=3).any(axis=1)  # [tasks, groups]: a finite delta on every seed
        with warnings.catch_warnings():  # an all-+inf (task, seed, group) has no mean: never a candidate below
            warnings.simplefilter("ignore", RuntimeWarning)
            per_group = np.nanmean(np.nanmean(metrics[..., TWA], axis=3), axis=1)  # [tasks, groups]
        for method in ("rnd_oe", "stac"):
            top = ceiling.selected[method].per_task()[0][:, TWA]
            members = [i for i, g in enumerate(groups) if g.method == method]
            for t in range(4):
                candidates = [per_group[t, i] for i in members if usable[t, i]]
                assert top[t] == pytest.approx(max(candidates))
            for other in (paper, loto):
                if method in other.selected:
                    below = other.selected[method].per_task()[0][:, TWA]
                    assert np.all(np.isnan(below) | (below <= top + 1e-12))


def test_paper_task_is_reported_as_a_ceiling_beside_auto(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--synthetic-test", "24", "--synthetic-scale", "0.25",
                 "--tiny", "--methods", "elapsed,pca_kmeans", "--windows", "1-3", "--default-window", "1", "--deltas",
                 "0.3", "--no-default-combos", "--protocol", "loto,paper-task", "--auto", "--auto-windows", "1,3",
                 "--no-plots", "--no-cache", "--quiet", "--out", str(out)]) == 0
    text = (out / "results.md").read_text()
    assert "## Table 1: failure prediction, paper protocol chosen per task, the per-task ceiling" in text
    assert "so a figure here is the ceiling of what the sweep's configurations can reach" in text
    section = text[text.index("## --auto:"):]
    header = next(line for line in section.splitlines() if line.startswith("| Task"))
    assert "LOTO best (TWA)" in header and "ceiling: paper-task best (TWA)" in header
    document = json.loads((out / "results.json").read_text())
    ceiling, loto = (document["protocols"][p]["selected"]["pca_kmeans"]["tasks"] for p in ("paper-task", "loto"))
    for task in ("sorting", "stacking"):
        assert ceiling[task]["twa"]["mean"] >= loto[task]["twa"]["mean"]
