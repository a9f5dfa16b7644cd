"""``fiper evaluate --auto --auto-rule transfer`` and ``--write-prior``: each task's prior is ranked on the other tasks'
labelled metrics only (changing the task's labels leaves its choice unchanged), the chosen entry's metrics are
those the sweep measured for that configuration, and the prior written by a run is the one ``fiper calibrate``
reads."""
from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from fiper_ros.cli import main
from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, PROMISES, TRANSFER, AutoSettings
from fiper_ros.core.combination import SHAPE_KINDS
from fiper_ros.core.transfer import STATISTICS, Prior, PriorEntry, PriorError
from fiper_ros.evaluation.data import Dataset, DatasetError
from fiper_ros.evaluation.engine import EngineSettings, EvaluationResult, check_evaluation, run_evaluation
from fiper_ros.evaluation.errors import SettingsError
from fiper_ros.evaluation.methods import Combination, MethodSettings
from fiper_ros.evaluation.protocol import METRICS
from fiper_ros.evaluation.sweep import Group, SweepSettings
from fiper_ros.evaluation.synthetic import make_task
from fiper_ros.evaluation.transfer import (Member, at_equal_promise, entry_of, loto_priors, members_of, prior_order,
                                           rank_percentiles, ranked_prior)

RULE = AutoSettings(rule=TRANSFER)
DELTAS = (0.2, 0.3)


@pytest.fixture(scope="module")
def two_tasks() -> list[Dataset]:
    out = []
    for seed, task in enumerate(("sorting", "stacking")):
        rollouts = make_task(task, seed=seed + 5, calibration=12, test=24, scale=0.25)
        out.append(Dataset(task, rollouts.calibration, rollouts.test))
    return out


def _run(datasets: list[Dataset], method_settings: MethodSettings, prior: Prior | None = None,
         pooled: bool = False) -> EvaluationResult:
    kinds = SHAPE_KINDS if pooled else SweepSettings().kinds
    settings = EngineSettings(methods=("elapsed", "pca_kmeans", "progress"), seeds=(0,), method_settings=method_settings,
                              sweep=SweepSettings(windows=(1, 3), deltas=DELTAS, max_pool=(2,), kinds=kinds),
                              combinations=(Combination("both", ("pca_kmeans", "progress")),),
                              protocols=("loto",) if len(datasets) > 1 else ("paper",), auto=RULE, auto_prior=prior,
                              pooled=pooled, progress=False)
    return run_evaluation(datasets, settings)


def _flipped(dataset: Dataset) -> Dataset:
    """The same task with every test label flipped."""
    test = [replace(r, success=not r.success) for r in dataset.test]
    return Dataset(dataset.task, dataset.calibration, test)


@pytest.mark.parametrize("pooled", [False, True], ids=["per-task", "pooled"])
def test_a_tasks_choice_never_reads_its_labels_and_its_metrics_are_the_sweeps(
        two_tasks: list[Dataset], tiny_settings: MethodSettings, pooled: bool) -> None:
    """Per-task thresholds, and thresholds pooled over the tasks: the chosen entry calibrated on both tasks'
    successes, as the pooled sweep calibrates every configuration."""
    result = _run(two_tasks, tiny_settings, pooled=pooled)
    auto = result.auto
    assert auto is not None
    flipped = _run([_flipped(two_tasks[0]), two_tasks[1]], tiny_settings, pooled=pooled).auto
    assert flipped is not None
    # the first task's labels changed: its choices did not (its prior is the other task's)
    assert flipped.choices[0] == auto.choices[0] and flipped.records[0] == auto.records[0]
    assert [r["prior"]["tasks"] for r in auto.records[0][0]] == [["stacking"]] * len(DELTAS)
    # the other task's prior read them: its ranking moved (the test can fail)
    assert [r["prior"]["content_hash"] for r in flipped.records[1][0]] != \
        [r["prior"]["content_hash"] for r in auto.records[1][0]]
    # the chosen configuration's alarms are those the sweep computed for it (calibrated the same way)
    members = members_of(result.settings.methods, result.settings.combinations)
    keys = [None if (e := entry_of(g, members[g.method])) is None else e.key() for g in result.groups]
    for t in range(2):
        for k, record in enumerate(auto.records[t][0]):
            if record["chosen"] is None:
                assert auto.infinite[t, 0, k]
                continue
            g = keys.index(PriorEntry.from_dict(record["chosen"]).key())
            np.testing.assert_array_equal(auto.metrics["all"][t, 0, k], result.metrics["all"][t, 0, g, k])
            assert auto.held_out["all"][t, 0, k] == pytest.approx(result.sweep.held_out["all"][t, 0, g, k],
                                                                 nan_ok=True)
    # its q-AUC is the sweep's figure of the configuration chosen at the delta it is shown at (the sweep computes
    # every configuration's at once); pooled over the tasks, each under its own choice
    assert auto.early is not None
    for t in range(2):
        record = auto.records[t][0][auto.shown(t)]
        g = keys.index(PriorEntry.from_dict(record["chosen"]).key())
        assert auto.early.q_auc[t, 0] == pytest.approx(result.sweep.early["q_auc"][t, 0, g], nan_ok=True)
        assert auto.early.auroc[t, 0] == pytest.approx(result.sweep.early["auroc"][t, 0, g], nan_ok=True)
    assert np.isfinite(auto.early.pooled_q_auc).all()


GROUPS = [Group("logpzo", "1", "cp_band"), Group("logpzo", "3", "cp_constant"), Group("rnd_oe", "max2", "cp_scaled"),
          Group("rnd_oe", "2", "time_varying"), Group("fiper", "1/3", "cp_band", "or"),
          Group("fiper", "cum/3", "cp_band", "and"), Group("elapsed", "cum", "cp_constant"),
          Group("rnd_a", "1", "cp_band")]
MEMBERS = {"logpzo": Member(("logpzo",)), "rnd_oe": Member(("rnd_oe",)), "fiper": Member(("rnd_oe", "ace")),
           "elapsed": Member(("elapsed",)), "rnd_a": Member(("rnd_a",))}


def test_entries_of_the_sweeps_configurations() -> None:
    entries = [entry_of(g, MEMBERS[g.method]) for g in GROUPS]
    assert [e.label() if e else None for e in entries] == [
        "logpzo w1 cp_band", "logpzo w3 cp_constant", "rnd_oe max2 cp_scaled", None,
        "rnd_oe+ace rnd_oe w1, ace w3 cp_band or (2 delta)", None, "elapsed cum cp_constant", None]
    equalised = entry_of(Group("strong_quantile", "5", "cp_band", "kth:2"),
                         Member(("logpzo", "rnd_oe", "elapsed"), "quantile", 0.8))
    assert equalised is not None and equalised.windows == {"rnd_oe": 5, "logpzo": 5}
    assert equalised.equalise == "quantile" and equalised.aggregation == "window"


@settings(max_examples=30, deadline=None)
@given(arrays(np.float64, (3, 1, len(GROUPS), 2, len(METRICS)), elements=st.floats(0, 1)),
       arrays(np.float64, (1, len(GROUPS), 2, len(METRICS)), elements=st.floats(0, 1)),
       st.integers(0, 2), st.sampled_from(tuple(STATISTICS)))
def test_a_tasks_prior_is_the_same_whatever_its_own_rows(metrics: np.ndarray, other: np.ndarray, task: int,
                                                         statistic: str) -> None:
    datasets = _three()
    infinite = np.zeros(metrics.shape[:-1], dtype=bool)
    common = dict(members=MEMBERS, method_settings=MethodSettings(), seeds=(0,), deltas=(0.1, 0.2),
                  select_aggregations=("window", "max"), top=10, statistic=statistic, promise=ENTRY_PROMISE)
    before = loto_priors(datasets, GROUPS, metrics, infinite, **common)
    changed = metrics.copy()
    changed[task] = other
    after = loto_priors(datasets, GROUPS, changed, infinite, **common)
    assert after[task] == before[task]
    assert before[task].tasks == tuple(d.task for n, d in enumerate(datasets) if n != task)
    assert {p.selection["statistic"] for p in before} == {statistic}
    assert len(before[task].entries) == 5  # the five that keep a promise
    if statistic == "mean":
        twa = [e.twa for e in before[task].entries]
        assert twa == sorted(twa, reverse=True)


# Six configurations on two tasks (TWA per task), by hand. Mean TWA: 0.70, 0.71, 0.60, 0.75, 0.575, 0.675.
RANKED = [Group("logpzo", "1", "cp_band"), Group("logpzo", "2", "cp_band"), Group("logpzo", "3", "cp_band"),
          Group("rnd_oe", "1", "cp_band"), Group("rnd_oe", "2", "cp_band"), Group("logpzo", "4", "cp_band")]
PER_TASK = np.array([[0.9, 0.7, 0.6, 1.0, 0.3, 0.8],
                     [0.5, 0.72, 0.6, 0.5, 0.85, 0.55]])
BY_HAND = {
    "mean": [3, 1, 0, 5, 2, 4],
    # minima 0.5, 0.7, 0.6, 0.5, 0.3, 0.55; 0 and 3 tie at 0.5, the better mean (3) first
    "worst": [1, 2, 5, 3, 0, 4],
    # percentiles on task a 0.8, 0.4, 0.2, 1, 0, 0.6; on task b 0.1, 0.8, 0.6, 0.1 (0 and 3 tie: the mean of ranks 0
    # and 1 of 5), 1, 0.4; means 0.45, 0.6, 0.4, 0.55, 0.5, 0.5: 4 and 5 tie, the better mean (5) first
    "rank": [1, 3, 5, 4, 0, 2],
    # logpzo's windows 1-4 are grid steps 0-3: w1 averages w1-w3 (0.67), w2 and w3 all four (0.67125), w4 w2-w4
    # (0.661667); rnd_oe's w1 and w2 both (0.6625): ties by the mean
    "smooth": [1, 2, 0, 3, 4, 5],
    # logpzo's four mean 0.67125, rnd_oe's two 0.6625: every logpzo configuration first, each method's by its mean
    "family": [1, 0, 5, 2, 3, 4],
}


@pytest.mark.parametrize("statistic", tuple(STATISTICS))
def test_each_prior_statistic_ranks_by_hand(statistic: str) -> None:
    mean = PER_TASK.mean(axis=0)
    assert prior_order(RANKED, PER_TASK, mean, range(6), statistic) == BY_HAND[statistic]
    # a candidate subset is ranked among itself
    subset = [i for i in BY_HAND[statistic] if i != 1]
    assert sorted(prior_order(RANKED, PER_TASK, mean, subset, statistic)) == sorted(subset)
    # a task whose TWA is undefined (no failures) is left out, not a NaN that scrambles the order
    undefined = np.vstack([PER_TASK, np.full(6, np.nan)])
    assert prior_order(RANKED, undefined, mean, range(6), statistic) == BY_HAND[statistic]


def test_rank_percentiles_by_hand_and_an_unknown_statistic_is_refused() -> None:
    np.testing.assert_allclose(rank_percentiles(np.array([0.5, 0.2, 0.5, 0.9])), [0.5, 0.0, 0.5, 1.0])
    np.testing.assert_array_equal(rank_percentiles(np.array([0.3, np.nan])), [1.0, np.nan])
    np.testing.assert_allclose(rank_percentiles(np.array([0.5, np.nan, 0.2])), [1.0, np.nan, 0.0])
    with pytest.raises(PriorError, match=r"prior statistic 'luck'; expected one of mean, worst, rank, family, smooth"):
        prior_order(RANKED, PER_TASK, PER_TASK.mean(axis=0), range(6), "luck")
    with pytest.raises(SettingsError, match=r"--prior-statistic 'luck'; expected one of"):
        EngineSettings(prior_statistic="luck")


def test_the_priors_of_a_run_rank_at_its_promise_by_that_promises_statistic() -> None:
    assert (EngineSettings().promise, EngineSettings().statistic) == (DELTA_PROMISE, "rank")
    assert EngineSettings(promise=ENTRY_PROMISE).statistic == "mean"
    assert EngineSettings(promise=ENTRY_PROMISE, prior_statistic="worst").statistic == "worst"
    with pytest.raises(SettingsError, match=r"--auto-promise 'loose'; expected one of entry, delta"):
        EngineSettings(promise="loose")
    with pytest.raises(SettingsError, match=r"--auto keeps promise 'entry', the run's priors rank at 'delta'"):
        EngineSettings(auto=AutoSettings(rule=TRANSFER, promise=ENTRY_PROMISE))


def test_the_prior_header_records_its_statistic() -> None:
    metrics = np.zeros((3, 1, len(RANKED), 1, len(METRICS)))
    metrics[:2, 0, :, 0, METRICS.index("twa")] = PER_TASK
    metrics[2, 0, :, 0, METRICS.index("twa")] = np.nan  # a task without failures: its TWA is undefined
    members = {"logpzo": Member(("logpzo",)), "rnd_oe": Member(("rnd_oe",))}
    for statistic in STATISTICS:
        prior = ranked_prior(RANKED, metrics, np.zeros(metrics.shape[:-1], dtype=bool), ("a", "b", "c"), members,
                             ("window",), 6, {}, statistic, ENTRY_PROMISE)
        assert prior.selection["statistic"] == statistic and prior.selection["ranks_by"] == STATISTICS[statistic]
        assert [e.label() for e in prior.entries] == [f"{RANKED[i].method} w{RANKED[i].window} cp_band"
                                                      for i in BY_HAND[statistic]]


_DATASETS: list[Dataset] = []


def _three() -> list[Dataset]:
    if not _DATASETS:
        rollouts = make_task("sorting", seed=1, calibration=4, test=4, scale=0.25)
        _DATASETS.extend(Dataset(name, rollouts.calibration, rollouts.test) for name in ("a", "b", "c"))
    return _DATASETS


def test_one_task_needs_a_prior_file_and_takes_it(tmp_path: Path, two_tasks: list[Dataset],
                                                   tiny_settings: MethodSettings) -> None:
    settings = EngineSettings(methods=("elapsed", "pca_kmeans"), method_settings=tiny_settings, auto=RULE)
    with pytest.raises(DatasetError) as error:
        check_evaluation(two_tasks[:1], settings)
    assert str(error.value) == ("--auto-rule transfer takes each task's prior from the other tasks' labelled rollouts: "
                                "with one task (sorting) give a prior file, --auto-prior FILE")
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--synthetic-test", "24", "--synthetic-scale", "0.25",
                 "--tiny", "--methods", "elapsed,pca_kmeans,progress", "--windows", "1-3", "--default-window", "1",
                 "--deltas", "0.3", "--no-plots", "--no-cache", "--quiet", "--out", str(out),
                 "--write-prior", str(tmp_path / "prior.yaml"), "--prior-top", "7", "--prior-statistic", "rank"]) == 0
    prior = Prior.load(tmp_path / "prior.yaml")
    assert prior.selection["statistic"] == "rank" and "pooled" not in prior.calibration
    assert prior.tasks == ("sorting", "stacking") and len(prior.entries) == 7
    assert "--write-prior" in prior.command and prior.command.startswith("fiper evaluate --synthetic")
    result = _run(two_tasks[:1], tiny_settings, prior)
    assert result.auto is not None and result.auto.records[0][0][0]["prior"]["content_hash"] == prior.content_hash
    out = tmp_path / "one"
    assert main(["evaluate", "--synthetic", "sorting", "--synthetic-test", "24", "--synthetic-scale", "0.25", "--tiny",
                 "--methods", "elapsed,pca_kmeans,progress", "--windows", "1-3", "--default-window", "1", "--deltas",
                 "0.3", "--no-plots", "--no-cache", "--quiet", "--out", str(out), "--auto", "--auto-rule", "transfer",
                 "--auto-prior", str(tmp_path / "prior.yaml")]) == 0
    text = (out / "results.md").read_text()
    assert "Rule transfer v1 (docs/method.md, 'The third rule')" in text
    assert "The prior's tasks: sorting: sorting, stacking." in text
    document = json.loads((out / "results.json").read_text())
    assert document["auto"]["tasks"]["sorting"]["record"]["rule"] == "transfer"


@pytest.mark.parametrize("promise", [ENTRY_PROMISE, DELTA_PROMISE])
def test_the_report_says_a_pooled_choice_promises_over_all_tasks_and_which_promise(tmp_path: Path,
                                                                                    promise: str) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--synthetic-test", "24", "--synthetic-scale", "0.25",
                 "--tiny", "--methods", "elapsed,pca_kmeans", "--windows", "1-3", "--default-window", "1", "--pool",
                 "--deltas", "0.3", "--no-plots", "--no-cache", "--quiet", "--out", str(out), "--auto", "--auto-rule",
                 "transfer", "--auto-promise", promise]) == 0
    text = (out / "results.md").read_text()
    assert "Thresholds pooled over the tasks (--pool): each choice is calibrated on every task's successes" in text
    read = "against δ. " if promise == DELTA_PROMISE else "against δ, or N δ where the choice is such an OR. "
    assert f"The promise (--auto-promise {promise}): {PROMISES[promise]}, so its FA column is to be read {read}" in text


def test_a_prior_of_a_pooled_run_says_so_and_one_without_transfer_is_refused(tiny_settings: MethodSettings,
                                                                            tmp_path: Path) -> None:
    out = tmp_path / "eval"
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--synthetic-test", "24", "--synthetic-scale", "0.25",
                 "--tiny", "--methods", "elapsed,pca_kmeans", "--windows", "1-3", "--default-window", "1", "--pool",
                 "--deltas", "0.3", "--no-plots", "--no-cache", "--quiet", "--out", str(out), "--write-prior",
                 str(tmp_path / "prior.yaml")]) == 0
    prior = Prior.load(tmp_path / "prior.yaml")
    assert prior.calibration["pooled"] is True and all(e.kind in SHAPE_KINDS for e in prior.entries)
    with pytest.raises(SettingsError, match="--auto-prior is the prior of --auto --auto-rule transfer"):
        EngineSettings(method_settings=tiny_settings, auto=AutoSettings(), auto_prior=Prior((), ("a",)))


def test_at_equal_promise_an_or_is_ranked_by_its_figures_at_the_promises_of_the_others() -> None:
    groups = [Group("logpzo", "1", "cp_band"), Group("fiper", "1/1", "cp_band", "or")]
    metrics = np.zeros((1, 1, 2, 2, len(METRICS)))
    twa = METRICS.index("twa")
    metrics[0, 0, 0, :, twa] = [0.7, 0.7]
    metrics[0, 0, 1, :, twa] = [0.6, 0.9]  # the OR of two: promise 0.1 at delta 0.05, 0.2 at delta 0.1
    infinite = np.zeros(metrics.shape[:-1], dtype=bool)
    header = {"deltas": (0.05, 0.1)}
    kept, never = at_equal_promise(groups, MEMBERS, metrics, infinite, header["deltas"])
    assert np.isnan(kept[0, 0, 1, 1]).all() and never[0, 0, 1].tolist() == [False, True]
    np.testing.assert_array_equal(kept[0, 0, 0], metrics[0, 0, 0])  # one threshold: every delta kept
    assert not infinite.any() and metrics[0, 0, 1, 1, twa] == 0.9  # the inputs are not changed
    own = ranked_prior(groups, metrics, infinite, ("a",), MEMBERS, ("window",), 2, header, "mean", ENTRY_PROMISE)
    assert [e.combine for e in own.entries] == ["or", ""] and own.entries[0].twa == pytest.approx(0.75)
    equal = ranked_prior(groups, metrics, infinite, ("a",), MEMBERS, ("window",), 2, header, "mean", DELTA_PROMISE)
    assert [e.combine for e in equal.entries] == ["", "or"] and equal.entries[1].twa == pytest.approx(0.6)
    assert equal.selection["promise"] == DELTA_PROMISE and own.selection["promise"] == ENTRY_PROMISE
    # an OR of three at deltas (0.05, 0.1): no delta whose triple is one of them, so no entry
    triple = {"three": Member(("rnd_oe", "logpzo", "pca_kmeans"))}
    alone = [Group("three", "1", "cp_band", "or")]
    with pytest.raises(PriorError, match="no configuration of the run on a can be a prior entry"):
        ranked_prior(alone, metrics[:, :, 1:], infinite[:, :, 1:], ("a",), triple, ("window",), 2, header, "mean",
                     DELTA_PROMISE)
    # a sweep whose OR thresholds are at delta / N (--or-promise delta): its figures are already at promise delta
    swept = ranked_prior(groups, metrics, infinite, ("a",), MEMBERS, ("window",), 2, header, "mean", DELTA_PROMISE,
                         DELTA_PROMISE)
    assert [e.combine for e in swept.entries] == ["or", ""] and swept.entries[0].twa == pytest.approx(0.75)
    assert "delta / N each" in swept.selection["twa"]
    assert ranked_prior(alone, metrics[:, :, 1:], infinite[:, :, 1:], ("a",), triple, ("window",), 2, header, "mean",
                        DELTA_PROMISE, DELTA_PROMISE).entries[0].combine == "or"
    with pytest.raises(ValueError, match="a prior at promise 'entry' needs each OR's figures at delta each"):
        ranked_prior(groups, metrics, infinite, ("a",), MEMBERS, ("window",), 2, header, "mean", ENTRY_PROMISE,
                     DELTA_PROMISE)


def test_a_choice_at_the_delta_promise_is_the_sweeps_or_at_delta_over_n(two_tasks: list[Dataset],
                                                                       tiny_settings: MethodSettings) -> None:
    deltas = (0.15, 0.3)
    kinds = SweepSettings().kinds

    def run(auto: AutoSettings, prior: Prior | None, or_promise: str = ENTRY_PROMISE) -> EvaluationResult:
        settings = EngineSettings(methods=("elapsed", "pca_kmeans", "progress"), seeds=(0,),
                                  method_settings=tiny_settings,
                                  sweep=SweepSettings(windows=(1, 3), deltas=deltas, max_pool=(2,), kinds=kinds,
                                                      or_promise=or_promise),
                                  combinations=(Combination("both", ("pca_kmeans", "progress")),), protocols=("loto",),
                                  auto=auto, auto_prior=prior, progress=False, promise=auto.promise)
        return run_evaluation(two_tasks, settings)

    own_promise = AutoSettings(rule=TRANSFER, promise=ENTRY_PROMISE)
    result = run(own_promise, None)
    members = members_of(result.settings.methods, result.settings.combinations)
    g = next(i for i, group in enumerate(result.groups)
             if group.method == "both" and group.combine == "or" and group.kind == "cp_band" and group.window == "1")
    entry = entry_of(result.groups[g], members["both"])
    assert entry is not None and entry.promised_multiple == 2
    prior = Prior((entry,), ("elsewhere",), (0,), deltas, {"subset": "all", "statistic": "mean"})
    # the test can fail: the OR's alarms at 0.15 are not those at 0.3
    assert any(not np.array_equal(result.metrics["all"][t, 0, g, 0], result.metrics["all"][t, 0, g, 1])
               for t in range(2))
    halved = run(RULE, prior, DELTA_PROMISE)  # the sweep's OR at delta / 2 in the column of delta
    split = halved.auto  # the default promise: delta
    own = run(own_promise, prior).auto
    assert split is not None and own is not None
    for t in range(2):
        # its own promise: the OR at each delta is the sweep's at that delta
        np.testing.assert_array_equal(own.metrics["all"][t, 0], result.metrics["all"][t, 0, g])
        # promise delta at 0.3: its thresholds at 0.15 each, the sweep's OR at 0.15
        np.testing.assert_array_equal(split.metrics["all"][t, 0, 1], result.metrics["all"][t, 0, g, 0])
        np.testing.assert_array_equal(halved.metrics["all"][t, 0, g, 1], result.metrics["all"][t, 0, g, 0])
        assert split.held_out["all"][t, 0, 1] == pytest.approx(result.sweep.held_out["all"][t, 0, g, 0], nan_ok=True)
        assert split.records[t][0][1]["threshold_delta"] == pytest.approx(0.15)
        assert split.choices[t][0][1].endswith("at delta/2 each")
        # at 0.15 its thresholds would take 0.075: 6 conformal successes are too few, no entry fits
        assert split.records[t][0][0]["chosen"] is None and split.infinite[t, 0, 0]


def test_the_entry_promise_is_refused_with_another_rule(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["evaluate", "--synthetic", "sorting,stacking", "--tiny", "--methods", "elapsed", "--no-plots",
                 "--quiet", "--out", str(tmp_path), "--auto", "--auto-promise", "entry"]) == 2
    assert capsys.readouterr().err.strip().endswith(
        "--auto-promise entry applies to the transfer rule: the proxy-twa rule's candidates promise delta (joint "
        "combines only)")
