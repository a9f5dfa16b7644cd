"""``fiper evaluate`` writes results.md (Tables 1 and 2), results.json and the PNGs."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.core.rollout import Rollout, RolloutSet
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.sweep import SweepSettings


def test_cli_writes_markdown_json_and_pngs(tmp_path: Path, tiny_dataset: Dataset, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    out = tmp_path / "out"
    argv = ["evaluate", "--data", f"sorting={data}", "--synthetic", "push_t", "--synthetic-scale", "0.25",
            "--synthetic-test", "16", "--tiny", "--windows", "1-4", "--default-window", "2", "--deltas", "0.1,0.2", "--seeds", "0,1",
            "--protocol", "paper,clean", "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "--quiet"]
    assert main(argv) == 0
    summary = capsys.readouterr().out
    assert "fiper evaluate: 2 task(s), 10 method(s), 2 seed(s)" in summary and "results.md" in summary
    assert "over the elapsed time" in summary
    assert "cache 4 hit(s), 32 miss(es)" in summary  # STAC and the elapsed time fit nothing: reused for seed 1
    markdown = (out / "results.md").read_text()
    for text in ("SYNTHETIC", "## Table 1", "## Table 2", "clean protocol", "| Elapsed |", "| FIPER |",
                 "| sorting | TWA ↑ |", "| Average | TWA ↑ |", "| | TWA − Elapsed |", "| AND | CP band |",
                 "| OR | time-var. |", "| OR | CP scaled |", "Fixed default configuration", "Calibration: split conformal",
                 "## The promise: false alarms on held-out ID successes, paper protocol", "FA / TPR at δ = 0.1"):
        assert text in markdown, text
    sizes = f"{len(tiny_dataset.calibration_successes)} calibration successes, {len(tiny_dataset.test)} test rollouts"
    assert f"Tasks: sorting ({sizes}, SYNTHETIC); push_t (50 calibration successes, 16 test rollouts, SYNTHETIC)." \
        in markdown  # what each figure names at its foot too; the tiny data set is synthetic as well
    document = json.loads((out / "results.json").read_text())
    assert document["synthetic"] is True
    assert set(document["protocols"]) == {"paper", "clean"}
    fiper = document["protocols"]["paper"]["selected"]["fiper"]
    assert len(fiper["tasks"]["sorting"]["twa"]["seeds"]) == 2
    assert len(document["sweep"]) > 100
    for png in ("scores_by_category.png", "window_impact.png", "delta_impact.png", "example_rollouts.png"):
        assert (out / png).stat().st_size > 10_000, png
    assert main(argv) == 0  # second run: every score stream from the cache
    assert "cache 36 hit(s), 0 miss(es)" in capsys.readouterr().out  # 2 tasks x 2 seeds x 9 streams
    same = out.parent / "same"
    assert main([*argv[:-5], "--out", str(same), "--cache-dir", str(tmp_path / "cache"), "--quiet", "--no-plots",
                 "--split", "same"]) == 0
    # STAC and the elapsed time from the first run; ACE, seedless with the same data, for seed 1
    assert "cache 10 hit(s), 26 miss(es)" in capsys.readouterr().out
    assert "Calibration: same data (the paper's Remark 1)" in (same / "results.md").read_text()
    assert json.loads((same / "results.json").read_text())["settings"]["calibration_split"] == {"split": "same"}


def test_cli_reports_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--data", f"x={tmp_path / 'missing.npz'}", "--out", str(tmp_path)]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["evaluate", "--out", str(tmp_path)]) == 2
    assert main(["evaluate", "--synthetic", "sorting", "--windows", "1-3", "--out", str(tmp_path)]) == 2
    assert "default window 5 is not among the swept windows" in capsys.readouterr().err
    # refused before the data is read (it was said only after loading every bag): the missing data is not named
    assert main(["evaluate", "--data", f"x={tmp_path / 'missing'}", "--windows", "1", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().endswith("the default window 5 is not among the swept windows")


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``fiper evaluate``; it must refuse with exit 2 and one line on stderr, and write nothing."""
    assert main(["evaluate", *argv, "--tiny", "--windows", "1-2", "--default-window", "1", "--deltas", "0.2",
                 "--no-cache", "--no-plots", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fiper evaluate: ") and "Traceback" not in err, err
    return err.strip()


def _npz(path: Path, dataset: Dataset, change: Callable[[Rollout], Rollout] = lambda r: r,
         which: slice = slice(None)) -> Path:
    """``dataset`` as a rollout set, with ``change`` applied to the test rollouts in ``which``."""
    test = list(dataset.test)
    test[which] = [change(r) for r in test[which]]
    RolloutSet(dataset.calibration, test).save_npz(path)
    return path


def test_a_stac_setting_error_is_one_line_before_any_work(tmp_path: Path, tiny_dataset: Dataset,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """STAC needs chunks that overlap (h < H): h = H used to stop the run with a traceback after the scores of
    the other methods were computed."""
    def whole(r: Rollout) -> Rollout:
        return replace(r, exec_steps=r.actions.shape[2])

    data = tmp_path / "hH.npz"
    RolloutSet([whole(r) for r in tiny_dataset.calibration], [whole(r) for r in tiny_dataset.test]).save_npz(data)
    err = _refused(["--data", f"sorting={data}", "--out", str(tmp_path / "out")], capsys)
    assert err == (f"fiper evaluate: task 'sorting', rollout {tiny_dataset.calibration[0].rollout_id!r}: STAC needs "
                   "1 <= h < H for an overlap, got h=8, H=8 (leave STAC out: --methods without stac)")
    assert _refused(["--data", f"sorting={data}", "--methods", "stac", "--out", str(tmp_path / "out")], capsys) == err
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("field, change, message", [
    ("E", lambda r: replace(r, embeddings=r.embeddings[:, :5]), "has E = 5, rollout {first} of {file} E = 32"),
    ("H", lambda r: replace(r, actions=r.actions[:, :, :6]), "has H = 6, rollout {first} of {file} H = 8"),
    ("D", lambda r: replace(r, actions=r.actions[..., :1]), "has D = 1, rollout {first} of {file} D = 2"),
    ("h", lambda r: replace(r, exec_steps=2), "has h = 2, rollout {first} of {file} h = 4"),
    ("action space", lambda r: replace(r, action_space="joint_position"),
     "has action space = joint_position, rollout {first} of {file} action space = ee_position"),
])
def test_rollouts_of_another_layout_are_named(tmp_path: Path, tiny_dataset: Dataset,
                                              capsys: pytest.CaptureFixture[str], field: str,
                                              change: Callable[[Rollout], Rollout], message: str) -> None:
    """One test rollout of another layout used to stop the run with a traceback deep in a score model."""
    data = _npz(tmp_path / "mixed.npz", tiny_dataset, change, slice(3, 4))
    err = _refused(["--data", f"sorting={data}", "--out", str(tmp_path / "out")], capsys)
    detail = message.format(first=repr(tiny_dataset.calibration[0].rollout_id), file=data)
    assert err == (f"fiper evaluate: {data}: rollout {tiny_dataset.test[3].rollout_id!r} {detail}: one task's rollouts "
                   "share one layout"), field


def test_a_bad_rollout_in_a_rollout_set_names_the_file(tmp_path: Path, tiny_dataset: Dataset,
                                                      capsys: pytest.CaptureFixture[str]) -> None:
    data = _npz(tmp_path / "nan.npz", tiny_dataset)
    arrays = dict(np.load(data, allow_pickle=False))
    arrays["test/2/embeddings"][1, 3] = np.nan
    np.savez(data, **arrays)
    err = _refused(["--data", f"sorting={data}", "--out", str(tmp_path / "out")], capsys)
    assert err == (f"fiper evaluate: {data}: rollout {tiny_dataset.test[2].rollout_id!r}: embeddings contains NaN/inf "
                   "(first at index [1, 3])")


def test_bad_settings_are_one_line(tmp_path: Path, tiny_dataset: Dataset, capsys: pytest.CaptureFixture[str]) -> None:
    data = _npz(tmp_path / "sorting.npz", tiny_dataset)
    out = ["--out", str(tmp_path / "out")]
    assert _refused(["--data", f"sorting={data}", "--data", f"sorting={data}", *out], capsys) == (
        "fiper evaluate: task names must be distinct, got ['sorting', 'sorting']")
    assert _refused(["--data", f"sorting={data}", "--seeds", "-1", *out], capsys) == (
        "fiper evaluate: seeds must be >= 0, got --seeds -1 and --split-seed 0")
    assert _refused(["--data", f"sorting={data}", "--split-seed", "-3", "--protocol", "clean", *out], capsys) == (
        "fiper evaluate: seeds must be >= 0, got --seeds 0 and --split-seed -3")
    cache = tmp_path / "cache-file"
    cache.write_text("")
    assert main(["evaluate", "--data", f"sorting={data}", "--cache-dir", str(cache), *out]) == 2
    assert capsys.readouterr().err == f"fiper evaluate: {cache} exists and is not a directory\n"
    assert not (tmp_path / "out").exists()
    with pytest.raises(SettingsError, match="at least one"):
        SweepSettings(deltas=())


def test_a_test_set_without_id_successes_has_no_false_alarm_rate(tmp_path: Path, tiny_dataset: Dataset,
                                                                capsys: pytest.CaptureFixture[str]) -> None:
    """No held-out ID success: the promise's table says n = 0 and no rate (before: a traceback in the sweep)."""
    test = [r for r in tiny_dataset.test if r.is_ood or not r.success]
    data = tmp_path / "no_id_successes.npz"
    RolloutSet(tiny_dataset.calibration, test).save_npz(data)
    argv = ["evaluate", "--data", f"sorting={data}", "--methods", "elapsed,stac", "--windows", "1-2",
            "--default-window", "1", "--deltas", "0.2", "--no-cache", "--no-plots", "--quiet",
            "--out", str(tmp_path / "out")]
    assert main(argv) == 0
    capsys.readouterr()
    rows = [line for line in (tmp_path / "out" / "results.md").read_text().splitlines()
            if line.startswith("| Elapsed | w cumulative, CP constant | ≤ δ | sorting |")]
    assert rows and all("| sorting | 0 | – |" in row for row in rows), rows


def test_equalised_combinations_are_swept_beside_the_plain_ones(tmp_path: Path, tiny_dataset: Dataset,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    """--equalise quantile,tail: each combination of several detectors again per kind, with the joint combines only;
    a one-detector combination (a logged signal alone) is not repeated."""
    data = _npz(tmp_path / "sorting.npz", tiny_dataset)
    out = tmp_path / "out"
    assert main(["evaluate", "--data", f"sorting={data}", "--tiny", "--methods", "elapsed,pca_kmeans", "--windows",
                 "1-2", "--default-window", "1", "--deltas", "0.2", "--no-default-combos", "--combo",
                 "both=pca_kmeans+elapsed", "--combo", "one=pca_kmeans", "--equalise", "quantile,tail",
                 "--equalise-level", "0.8", "--no-cache", "--no-plots", "--quiet", "--out", str(out)]) == 0
    capsys.readouterr()
    combines: dict[str, set[str]] = {}
    kinds: dict[str, set[str]] = {}
    for row in json.loads((out / "results.json").read_text())["sweep"]:
        combines.setdefault(row["method"], set()).add(row["combine"])
        kinds.setdefault(row["method"], set()).add(row["threshold"])
    assert combines["both"] == {"max", "kth:2", "and", "or"} and combines["one"] == {""}
    assert combines["both_quantile"] == combines["both_tail"] == {"max", "kth:2"}
    # quantile equalisation divides by a positive quantile of the maxima, which the constant shape centres on 0
    assert kinds["both_tail"] == {"cp_band", "cp_scaled", "cp_constant"}
    assert kinds["both_quantile"] == {"cp_band", "cp_scaled"}
    assert "one_tail" not in combines
    with pytest.raises(SystemExit):  # argparse: the plain combination is always swept, "none" is no extra kind
        main(["evaluate", "--data", f"sorting={data}", "--equalise", "none", "--out", str(tmp_path / "x")])
    assert "argument --equalise: unknown ['none']; choose from quantile, tail" in capsys.readouterr().err
