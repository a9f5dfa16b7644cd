"""``fiper evaluate`` writes results.md (Tables 1 and 2), results.json and the PNGs."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fiper_ros.cli import main
from fiper_ros.core.rollout import RolloutSet
from fiper_ros.evaluation.data import Dataset


def test_cli_writes_markdown_json_and_pngs(tmp_path: Path, tiny_dataset: Dataset, capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    out = tmp_path / "out"
    argv = ["evaluate", "--data", f"sorting={data}", "--synthetic", "push_t", "--synthetic-scale", "0.25",
            "--synthetic-test", "16", "--tiny", "--windows", "1-4", "--default-window", "2", "--deltas", "0.1,0.2", "--seeds", "0,1",
            "--protocol", "paper,clean", "--out", str(out), "--cache-dir", str(tmp_path / "cache"), "--quiet"]
    assert main(argv) == 0
    summary = capsys.readouterr().out
    assert "fiper evaluate: 2 task(s), 8 method(s), 2 seed(s)" in summary and "results.md" in summary
    assert "over the elapsed time" in summary
    assert "cache 4 hit(s), 24 miss(es)" in summary  # STAC and the elapsed time fit nothing: reused for seed 1
    markdown = (out / "results.md").read_text()
    for text in ("SYNTHETIC", "## Table 1", "## Table 2", "clean protocol", "| Elapsed |", "| FIPER |",
                 "| sorting | TWA ↑ |", "| Average | TWA ↑ |", "| | TWA − Elapsed |", "| AND | CP band |",
                 "| OR | time-var. |", "| OR | CP scaled |", "Fixed default configuration", "Calibration: split conformal",
                 "## The promise: false alarms on held-out ID successes, paper protocol", "FA / TPR at δ = 0.1"):
        assert text in markdown, text
    document = json.loads((out / "results.json").read_text())
    assert document["synthetic"] is True
    assert set(document["protocols"]) == {"paper", "clean"}
    fiper = document["protocols"]["paper"]["selected"]["fiper"]
    assert len(fiper["tasks"]["sorting"]["twa"]["seeds"]) == 2
    assert len(document["sweep"]) > 100
    for png in ("scores_by_category.png", "window_impact.png", "delta_impact.png", "example_rollouts.png"):
        assert (out / png).stat().st_size > 10_000, png
    assert main(argv) == 0  # second run: every score stream from the cache
    assert "cache 28 hit(s), 0 miss(es)" in capsys.readouterr().out  # 2 tasks x 2 seeds x 7 streams
    same = out.parent / "same"
    assert main([*argv[:-5], "--out", str(same), "--cache-dir", str(tmp_path / "cache"), "--quiet", "--no-plots",
                 "--split", "same"]) == 0
    # STAC and the elapsed time from the first run; ACE, seedless with the same data, for seed 1
    assert "cache 10 hit(s), 18 miss(es)" in capsys.readouterr().out
    assert "Calibration: same data (the paper's Remark 1)" in (same / "results.md").read_text()
    assert json.loads((same / "results.json").read_text())["settings"]["calibration_split"] == {"split": "same"}


def test_cli_reports_bad_input(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--data", f"x={tmp_path / 'missing.npz'}", "--out", str(tmp_path)]) == 2
    assert "not found" in capsys.readouterr().err
    assert main(["evaluate", "--out", str(tmp_path)]) == 2
    assert main(["evaluate", "--synthetic", "sorting", "--windows", "1-3", "--out", str(tmp_path)]) == 2
    assert "default window 5 is not among the swept windows" in capsys.readouterr().err
