"""The leave-one-task-out protocol: each task's configuration chosen without its labels, reported on it."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import EngineSettings, run_evaluation
from fiper_ros.evaluation.methods import MethodSettings
from fiper_ros.evaluation.protocol import METRICS, run_loto, run_protocol
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
