"""``fiper evaluate --auto``: each task's configuration is exactly the one ``fiper calibrate --auto`` chooses on its
calibration successes, and its reported metrics are those of that calibration's alarms on the test rollouts."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.core.auto import AutoSettings
from fiper_ros.core.calibration import CalibrationSettings, auto_calibrate
from fiper_ros.core.metrics import evaluate
from fiper_ros.core.monitor import predict_rollout
from fiper_ros.core.thresholds import GUARANTEED_KINDS
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import EngineSettings, run_evaluation
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.methods import Combination, MethodSettings
from fiper_ros.evaluation.protocol import METRICS
from fiper_ros.evaluation.sweep import SweepSettings
from fiper_ros.evaluation.transfer import entry_of, entry_of_choice, members_of

AUTO = AutoSettings(windows=(1, 3), folds=3)
DELTA = 0.3


def test_the_evaluated_choice_is_calibrate_autos_and_so_are_its_alarms(tiny_dataset: Dataset,
                                                                      tiny_settings: MethodSettings) -> None:
    settings = EngineSettings(methods=("elapsed", "pca_kmeans", "progress"), seeds=(1,), method_settings=tiny_settings,
                              sweep=SweepSettings(windows=(1, 3), deltas=(DELTA,), kinds=GUARANTEED_KINDS),
                              combinations=(Combination("both", ("pca_kmeans", "progress")),), auto=AUTO,
                              progress=False)
    result = run_evaluation([tiny_dataset], settings)
    outcome = result.auto
    assert outcome is not None
    ms = tiny_settings
    core = CalibrationSettings(rnd=ms.rnd, logpzo=ms.logpzo, pca_kmeans=ms.pca_kmeans, progress=ms.progress,
                               consistency=ms.consistency, delta=DELTA, seed=1)
    # calibration failures beside the successes: never read
    calibration, choice = auto_calibrate(tiny_dataset.calibration, core, AUTO, ("pca_kmeans", "progress", "elapsed"))
    assert outcome.records[0][0][0] == choice.record(top=5)
    assert outcome.choices == [[[choice.chosen.label()]]]
    steps = [predict_rollout(r, calibration).first_alarm_step for r in tiny_dataset.test]
    expected = evaluate(steps, [bool(f) for f in tiny_dataset.failed], [int(n) for n in tiny_dataset.lengths])
    np.testing.assert_array_equal(outcome.metrics["all"][0, 0, 0], [expected[m] for m in METRICS])
    assert not outcome.infinite.any()
    # its AUROC / q-AUC: the sweep's figures of that configuration
    members = members_of(settings.methods, settings.combinations)
    keys = [None if (e := entry_of(g, members[g.method])) is None else e.key() for g in result.groups]
    g = keys.index(entry_of_choice(outcome.records[0][0][0]).key())
    assert outcome.early is not None
    assert outcome.early.q_auc[0, 0] == pytest.approx(result.sweep.early["q_auc"][0, 0, g])
    assert outcome.early.auroc[0, 0] == pytest.approx(result.sweep.early["auroc"][0, 0, g])
    # a choice the sweep did not measure (only time-varying thresholds swept) has none
    alone = run_evaluation([tiny_dataset], replace(settings, sweep=replace(settings.sweep, kinds=("time_varying",)))).auto
    assert alone is not None and alone.choices == outcome.choices and alone.early is None


def test_evaluate_auto_reports_its_section(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--synthetic-test", "24", "--synthetic-scale", "0.25",
                 "--tiny", "--methods", "elapsed,pca_kmeans", "--windows", "1-3", "--default-window", "1", "--deltas", "0.3",
                 "--no-default-combos", "--protocol", "clean,loto", "--auto", "--auto-windows", "1,3", "--no-plots",
                 "--no-cache", "--quiet", "--out", str(out)]) == 0
    text = (out / "results.md").read_text()
    section = text[text.index("## --auto: each task's configuration chosen from its own calibration successes"):]
    rows = [line for line in section.splitlines() if line.startswith("| ")]
    assert rows[0].split(" | ")[:3] == ["| Task", "chosen (seed 0, at δ)", "TWA"]
    assert "LOTO best (TWA)" in rows[0] and "clean best, report half (TWA)" in rows[0]
    assert [r.split(" | ")[0] for r in rows[1:]] == ["| sorting", "| stacking", "| average"]
    document = json.loads((out / "results.json").read_text())
    assert set(document["auto"]["subsets"]) == {"all", "report"}
    # the gain over the elapsed time is taken on the same rollouts: all test rollouts (LOTO's elapsed), not the
    # clean protocol's report half
    gain_column = rows[0].split(" | ").index("TWA − Elapsed")
    elapsed = document["protocols"]["loto"]["selected"]["elapsed"]["tasks"]
    for row, task in zip(rows[1:3], ("sorting", "stacking")):
        expected = document["auto"]["subsets"]["all"][task]["twa"]["mean"] - elapsed[task]["twa"]["mean"]
        assert row.split(" | ")[gain_column] == f"{expected:+.2f}"
    assert document["auto"]["tasks"]["sorting"]["record"]["rule"] == "proxy-twa"
    # the choices' q-AUC has a column; here the choice (PCA-kmeans + elapsed time, max) is no configuration of the
    # sweep (--no-default-combos), so none, said in the cells, the text and results.json
    area_column = rows[0].split(" | ").index("q-AUC (average row: pooled)")
    assert document["auto"]["early_detection"] == {"undefined": "some choice is not a configuration of the sweep"}
    assert all(row.split(" | ")[area_column] == "–" for row in rows[1:])
    assert "q-AUC: that choice's on all test rollouts (threshold-free; none: some choice is not a configuration" in section
    assert "Rule proxy-twa v1 (docs/method.md, 'Choosing the configuration from successes'): candidates scored on " \
           "the fit part's successes by fold models, with stall, drift and skip proxies made from them;" in section


def test_evaluate_auto_rule_margin_says_what_it_reads(tmp_path: Path) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting", "--synthetic-test", "24", "--synthetic-scale", "0.25", "--tiny",
                 "--methods", "elapsed,pca_kmeans", "--windows", "1-3", "--default-window", "1", "--deltas", "0.3",
                 "--no-default-combos", "--protocol", "clean", "--auto", "--auto-rule", "margin", "--auto-windows",
                 "1,3", "--no-plots", "--no-cache", "--quiet", "--out", str(out)]) == 0
    text = (out / "results.md").read_text()
    assert "Rule margin v1 (docs/method.md, 'Choosing the configuration from successes'): candidates scored on the " \
           "fit part's held-out successes alone (fold models; no proxy)" in text
    assert "proxies" not in text[text.index("## --auto"):]
    document = json.loads((out / "results.json").read_text())
    assert document["auto"]["tasks"]["sorting"]["record"]["rule"] == "margin"


def test_evaluate_auto_needs_a_split_conformal_calibration(tiny_settings: MethodSettings) -> None:
    with pytest.raises(SettingsError, match=r"--auto chooses on the fit part"):
        EngineSettings(method_settings=replace(tiny_settings, split="same"), auto=AUTO)


def test_evaluate_auto_rules_that_calibrate_per_task_refuse_pooled_thresholds(tiny_settings: MethodSettings) -> None:
    """Its section would report per-task calibrations in a run whose thresholds are pooled (it did, silently)."""
    for rule in ("proxy-twa", "margin"):
        with pytest.raises(SettingsError) as error:
            EngineSettings(method_settings=tiny_settings, auto=replace(AUTO, rule=rule), pooled=True,
                           sweep=SweepSettings(kinds=("cp_band",)))
        assert str(error.value) == (f"--auto-rule {rule} is evaluated with each task's choice calibrated on that task "
                                    "alone, not pooled over the tasks (--pool): use --auto-rule transfer with --pool")
