"""The report: no silent infinities (a +inf threshold, too few conformal rollouts for delta, is never
averaged or selected, and every table shows it) and the promise (false alarms on held-out ID successes)."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.thresholds import conformal_quantile
from fiper_ros.evaluation.data import Dataset
from fiper_ros.evaluation.engine import EngineSettings, EvaluationResult, run_evaluation
from fiper_ros.evaluation.methods import ELAPSED, MethodSettings
from fiper_ros.evaluation.protocol import METRICS
from fiper_ros.evaluation.report import guarantee_text, json_document, markdown, promise_rows
from fiper_ros.evaluation.sweep import Group, SweepSettings
from fiper_ros.evaluation.synthetic import make_task

DELTAS = (0.05, 0.1)  # 19 and 9 conformal rollouts needed


@pytest.fixture(scope="module")
def result(tiny_dataset: Dataset) -> EvaluationResult:
    """Three tasks, split conformal: 6, 15 and 25 conformal rollouts (12, 30 and 50 calibration successes)."""
    partial = make_task("push_t", seed=4, calibration=30, test=16, scale=0.25)
    finite = make_task("push_t", seed=5, calibration=50, test=16, scale=0.25)
    datasets = [tiny_dataset, Dataset("partial", partial.calibration, partial.test),
                Dataset("finite", finite.calibration, finite.test)]
    settings = EngineSettings(methods=(ELAPSED, "ace", "fiper"), seeds=(0,), method_settings=MethodSettings.tiny(),
                              sweep=SweepSettings(windows=(1, 2), cumulative=False, deltas=DELTAS, pairs="diagonal"),
                              default_window=2, progress=False)
    return run_evaluation(datasets, settings)


def test_infinite_cells_are_recorded_and_have_no_metrics(result: EvaluationResult) -> None:
    sweep = result.sweep
    cp = [i for i, g in enumerate(result.groups) if g.kind != "time_varying"]
    varying = [i for i, g in enumerate(result.groups) if g.kind == "time_varying"]
    assert cp and varying
    # sorting (M = 6): every conformal kind is +inf at both deltas; partial (M = 15): at 0.05 only; finite: never
    assert sweep.infinite[0][:, cp].all() and sweep.infinite[1][:, cp, 0].all()
    assert not sweep.infinite[1][:, cp, 1].any() and not sweep.infinite[2].any()
    assert not sweep.infinite[:, :, varying].any()  # a per-step empirical quantile is always finite
    assert set(sweep.conformal[0, 0, cp].tolist()) == {6} and set(sweep.conformal[1, 0, cp].tolist()) == {15}
    assert np.isnan(sweep.metrics["all"][sweep.infinite]).all()
    assert not np.isnan(sweep.metrics["all"][~sweep.infinite][..., METRICS.index("tnr")]).any()


def test_infinite_cells_are_never_averaged_or_selected(result: EvaluationResult) -> None:
    paper = result.protocols["paper"]
    for method in ("ace", "fiper"):  # every conformal configuration is +inf on sorting: only time-varying is left
        assert paper.selected[method].group.kind == "time_varying"
    default = paper.default["ace"]
    assert default.group == Group("ace", "2", "cp_band")
    g = result.groups.index(default.group)
    metrics = result.metrics["all"]
    # the partial task's cell is its one finite delta (the +inf delta would add TPR 0, TNR 1)
    np.testing.assert_array_equal(default.values[1, 0], metrics[1, 0, g, 1])
    assert np.isnan(default.values[0, 0]).all()
    # the task average leaves sorting out
    np.testing.assert_allclose(default.average()[0], (metrics[1, 0, g, 1] + metrics[2, 0, g].mean(axis=0)) / 2)


def test_every_table_shows_them(result: EvaluationResult) -> None:
    text = markdown(result, [])
    assert "- sorting: CP constant, CP band, CP scaled over 6 rollouts: +inf at delta 0.05, 0.1." in text
    assert "- finite: CP constant, CP band, CP scaled over 25 rollouts: finite at every delta." in text
    default_table = text.split("## Fixed default configuration, paper protocol")[1].split("##")[0]
    sorting_twa = next(line for line in default_table.splitlines() if line.startswith("| sorting | TWA"))
    assert sorting_twa.count("inf (M=6 < 9)") == 3  # Elapsed, ACE, FIPER
    assert "| partial | TWA ↑ |" in default_table and "‡" in default_table
    assert "‡ partial: averaged over delta 0.1 only; +inf at delta 0.05 (M=15 < 19): Elapsed, ACE, FIPER." in text
    assert "‡ Average over 2 of 3 tasks (sorting: inf): Elapsed, ACE, FIPER." in text
    promise = text.split("## The promise: false alarms on held-out ID successes, paper protocol")[1].split("##")[0]
    assert "inf (M=6 < 19)" in promise and "inf (M=15 < 19)" in promise
    document = json_document(result)
    assert document["protocols"]["paper"]["default"]["ace"]["tasks"]["partial"]["infinite_deltas"] == [0.05]
    entry = next(e for e in document["sweep"] if (e["method"], e["window"], e["threshold"]) == ("ace", "2", "cp_band"))
    assert entry["infinite_deltas"] == {"sorting": [0.05, 0.1], "partial": [0.05]}
    assert entry["metrics"]["sorting"]["twa"] == [None, None]


def test_the_promise_rows_by_hand(result: EvaluationResult) -> None:
    """The elapsed-time baseline's held-out false alarms: the ID successes longer than k, k the conformal
    quantile of the conformal lengths."""
    t = 2  # the finite task
    dataset = result.datasets[t]
    lengths = [curve.shape[0] for curve in result.streams[dataset.task][ELAPSED].conformal]
    held_out = [dataset.test[i].length for i in dataset.held_out_id_successes]
    assert len(lengths) == 25 and held_out
    rows = promise_rows(result, result.protocols["paper"].selected[ELAPSED], t, "all", (ELAPSED,))
    for row, delta in zip(rows, DELTAS):
        k = conformal_quantile(lengths, delta)
        rate = sum(n > k for n in held_out) / len(held_out)
        assert (row["delta"], row["n"], row["rate"], row["infinite"]) == (delta, len(held_out), rate, False)
        assert row["standard_error"] == math.sqrt(rate * (1 - rate) / len(held_out))
        assert row["above"] == (rate > delta + 2 * row["standard_error"]) and row["promised"] == delta
    catalogue = result.settings.catalogue()
    flagged = [row for method, chosen in result.protocols["paper"].selected.items() for task in range(3)
               for row in promise_rows(result, chosen, task, "all", catalogue[method].streams) if row["above"]]
    assert flagged  # some selected (time-varying) configuration alarms on far more held-out successes than delta
    assert all(row["rate"] > row["promised"] + 2 * row["standard_error"] for row in flagged)
    assert "⚠" in markdown(result, [])


def test_an_or_of_n_thresholds_is_held_to_n_delta(result: EvaluationResult) -> None:
    """The union bound: FIPER's OR promises 2 delta, and its flag is against 2 delta + 2 sigma (it was held to
    delta + 2 sigma, which flagged a kept promise as broken)."""
    catalogue = result.settings.catalogue()
    fiper = next(chosen for protocol in result.protocols.values() for method, chosen in protocol.selected.items()
                 if catalogue[method].streams == ("rnd_oe", "ace") and chosen.group_of(2).combine == "or")
    rows = promise_rows(result, fiper, 2, "all", ("rnd_oe", "ace"))
    assert [row["promised"] for row in rows] == [2 * row["delta"] for row in rows]
    assert all(row["above"] == (row["rate"] > 2 * row["delta"] + 2 * row["standard_error"]) for row in rows
               if not math.isnan(row["rate"]))


def test_an_or_at_promise_delta_is_held_to_delta(result: EvaluationResult) -> None:
    """``--or-promise delta``: the same run's OR sets each threshold at delta / 2, so its flag is against delta + 2
    sigma, its guarantee says so, and the report and results.json say which promise the OR rows are at."""
    settings = result.settings
    halved = run_evaluation(result.datasets, replace(settings, sweep=replace(settings.sweep, or_promise="delta")))
    catalogue = settings.catalogue()
    checked = 0
    for protocol in halved.protocols.values():
        for method, chosen in protocol.selected.items():
            if catalogue[method].streams == ("rnd_oe", "ace") and chosen.group_of(2).combine == "or":
                rows = promise_rows(halved, chosen, 2, "all", ("rnd_oe", "ace"))
                assert [row["promised"] for row in rows] == [row["delta"] for row in rows]
                checked += 1
    assert checked
    band = replace(chosen, group=Group("fiper", "2/2", "cp_band", "or"), task_groups=())
    assert guarantee_text(band, "split", ("rnd_oe", "ace"), or_promise="delta") == "≤ δ (OR at δ/2 each)"
    assert guarantee_text(band, "split", ("rnd_oe", "ace")) == "≤ 2δ (OR)"
    assert "An OR of N thresholds sets each at δ/N (--or-promise delta)" in markdown(halved, [])
    assert json_document(halved)["settings"]["or_promise"] == "delta"
    assert json_document(result)["settings"]["or_promise"] == "entry"
