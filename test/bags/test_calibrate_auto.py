"""``fiper calibrate --auto``: on a bag of successes (and a failure it never needs), it chooses the configuration from
the successes alone, prints the best candidates and why the winner won, and stores the choice in the calibration;
the same choice as :func:`fiper_ros.core.calibration.auto.auto_calibrate` with the same settings."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.cli import main
from fiper_ros.commands.errors import UsageError
from fiper_ros.commands.options import DEFAULT_PRIOR, ENTRY_PRIOR, prior_from
from fiper_ros.core.auto import AutoSettings
from fiper_ros.core.calibration import CalibrationSettings, load_calibration
from fiper_ros.core.calibration.auto import auto_calibrate
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.transfer import Prior, PriorEntry


def _rollout(index: int, *, fail: bool = False) -> Rollout:
    """A success whose logged signals a and b are flat and noisy (a failure: b jumps at step 10)."""
    rng = np.random.default_rng(index)
    length = 20
    signals = {"a": 1.0 + 0.1 * rng.random(length), "b": 1.0 + 0.1 * rng.random(length)}
    if fail:
        signals["b"][10:] += 20.0
    return Rollout(f"r{index}", "synthetic", "id", rng.normal(size=(length, 4)).astype(np.float32), None, 1,
                   not fail, signals=signals)


@pytest.fixture(scope="module")
def signal_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("auto") / "bag"
    rollouts = [*(_rollout(i) for i in range(12)), _rollout(50, fail=True)]
    write_rollouts(path, rollouts, list(range(1, len(rollouts) + 1)),
                   BagInfo(task="synthetic", synthetic=True, source="test"))
    return path


def test_calibrate_auto_prints_and_stores_its_choice(tmp_path: Path, signal_bag: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--detectors", "signal_a,signal_b,elapsed",
                 "--auto-windows", "1,3", "--auto-folds", "3", "--delta", "0.3", "--seed", "2"]) == 0
    printed = capsys.readouterr().out
    calibration = load_calibration(out)
    record = calibration.auto
    assert record["rule"] == "proxy-twa" and record["detectors"] == ["elapsed", "signal_a", "signal_b"]
    assert list(calibration.settings.detectors) == record["chosen"]["detectors"]
    assert calibration.settings.shape_folds == 3 and calibration.num_rollouts == 12  # the failure is not used
    lines = printed.splitlines()
    head = lines.index(next(line for line in lines if line.startswith("auto (proxy-twa v1, delta 0.3): ")))
    assert lines[head + 1].split() == ["rank", "proxy", "TWA", "held-out", "FA", "stall", "drift", "skip",
                                       "candidate"]
    assert lines[head + 2].split()[0] == "1" and lines[head + 2].endswith(record["top"][0]["candidate"])
    assert f"chosen: {record['why']}" in lines
    settings = CalibrationSettings(detectors=("rnd_oe", "ace"), delta=0.3, seed=2)
    again, _ = auto_calibrate(read_rollouts(signal_bag), settings, AutoSettings(windows=(1, 3), folds=3),
                              ("signal_a", "signal_b", "elapsed"))
    assert again.auto == record and again.content_hash == calibration.content_hash


def test_calibrate_auto_refuses_a_budget_it_would_exceed(tmp_path: Path, signal_bag: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--detectors", "signal_a,elapsed",
                 "--auto-budget", "3", "--delta", "0.3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exceed the auto budget of 3 (--auto-budget)" in err
    assert not out.exists()


def test_calibrate_auto_rule_margin_prints_and_stores_its_margins(tmp_path: Path, signal_bag: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "margin", "--detectors",
                 "signal_a,signal_b,elapsed", "--auto-windows", "1,3", "--auto-folds", "3", "--delta", "0.3",
                 "--seed", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    record = load_calibration(out).auto
    assert record["rule"] == "margin" and record["settings"]["rule"] == "margin"
    head = lines.index(next(line for line in lines if line.startswith("auto (margin v1, delta 0.3): ")))
    assert lines[head + 1].split() == ["rank", "margin", "held-out", "FA", "candidate"]
    first = lines[head + 2].split()
    assert first[0] == "1" and float(first[1]) == pytest.approx(record["top"][0]["figures"]["margin"], abs=1e-3)
    assert "elapsed" not in record["chosen"]["detectors"]  # no spread: an infinite margin


PRIOR_ENTRIES = (
    PriorEntry(("rnd_oe", "ace"), "window", {"rnd_oe": 8, "ace": 50}, "cp_band", "or", method="fiper", twa=0.9),
    PriorEntry(("signal_b",), "window", {"signal_b": 3}, "cp_constant", method="signal_b", twa=0.8),
    PriorEntry(("signal_a",), "window", {"signal_a": 1}, "cp_band", method="signal_a", twa=0.7),
)


PRIOR_AT_DELTA = Prior(PRIOR_ENTRIES[1:], ("sorting", "stacking"), (0,), (0.3,),
                       {"statistic": "rank", "promise": "delta"}, {}, "hand-made", "by hand", "0")


@pytest.fixture()
def prior_file(tmp_path: Path) -> Path:
    return Prior(PRIOR_ENTRIES, ("sorting", "stacking"), (0,), (0.3,), {"statistic": "rank", "promise": "delta"}, {},
                 "hand-made", "by hand", "0").save(tmp_path / "prior.yaml")


def test_calibrate_auto_rule_transfer_takes_the_first_entry_it_can_feed(tmp_path: Path, signal_bag: Path,
                                                                       prior_file: Path,
                                                                       capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "transfer", "--auto-prior",
                 str(prior_file), "--delta", "0.3", "--seed", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    calibration = load_calibration(out)
    record = calibration.auto
    prior = Prior.load(prior_file)
    assert record["rule"] == "transfer" and record["rank"] == 2
    assert record["prior"]["content_hash"] == prior.content_hash and record["prior"]["tasks"] == ["sorting", "stacking"]
    assert calibration.settings.detectors == ("signal_b",) and calibration.settings.threshold == "cp_constant"
    assert calibration.settings.window_of("signal_b") == 3 and calibration.num_rollouts == 12
    head = lines.index(next(line for line in lines if line.startswith("auto (transfer v1, delta 0.3): prior ")))
    assert lines[head + 2].split()[:2] == ["1", "0.900"] and "skipped (need a detector the successes cannot feed)" \
        in lines[head + 2]
    assert lines[head + 3].split()[:2] == ["2", "0.800"] and lines[head + 3].endswith("signal_b w3 cp_constant: chosen")
    assert f"chosen: {record['why']}" in lines
    assert not any(line.startswith("note:") for line in lines)  # the prior and the calibration both per task


def test_calibrate_auto_rule_transfer_notes_a_prior_ranked_with_pooled_thresholds(
        tmp_path: Path, signal_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    prior = Prior(PRIOR_ENTRIES, ("sorting", "stacking"), (0,), (0.3,), {"statistic": "mean"}, {"pooled": True},
                  "hand-made", "by hand", "0").save(tmp_path / "prior.yaml")
    assert main(["calibrate", str(signal_bag), "-o", str(tmp_path / "calibration"), "--auto", "--auto-rule",
                 "transfer", "--auto-prior", str(prior), "--delta", "0.3", "--seed", "2"]) == 0
    assert ("note: the prior ranked its entries with thresholds pooled over the tasks, this calibration's are per task: "
            "its order may not carry over") in capsys.readouterr().out.splitlines()


def test_calibrate_auto_promise_delta_notes_a_prior_ranked_at_each_entrys_promise(
        tmp_path: Path, signal_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a prior written before promises were recorded: ranked at each entry's own
    prior = Prior(PRIOR_ENTRIES, ("sorting", "stacking"), (0,), (0.3,), {"statistic": "mean"}, {}, "hand-made",
                  "by hand", "0").save(tmp_path / "prior.yaml")
    assert main(["calibrate", str(signal_bag), "-o", str(tmp_path / "calibration"), "--auto", "--auto-rule",
                 "transfer", "--auto-prior", str(prior), "--delta", "0.3", "--seed", "2"]) == 0  # delta: the default
    assert ("note: the prior ranked its entries at promise 'entry', this choice keeps 'delta' (every choice promises "
            "delta: an OR of N thresholds is calibrated at delta / N each (the union bound)): its order may not carry "
            "over") in capsys.readouterr().out.splitlines()
    assert load_calibration(tmp_path / "calibration").auto["settings"]["promise"] == "delta"


def test_calibrate_auto_rule_transfer_refuses_a_modified_prior_in_one_line(tmp_path: Path, signal_bag: Path,
                                                                         prior_file: Path,
                                                                         capsys: pytest.CaptureFixture[str]) -> None:
    prior_file.write_text(prior_file.read_text().replace("twa: 0.8", "twa: 0.95"))
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "transfer", "--auto-prior",
                 str(prior_file), "--delta", "0.3"]) == 2
    err = capsys.readouterr().err
    assert err == (f"fiper calibrate: {prior_file}: content hash mismatch (the prior was modified after it was "
                   "written)\n")
    assert not out.exists()
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-prior", str(prior_file)]) == 2
    assert "--auto-prior is the prior of --auto --auto-rule transfer" in capsys.readouterr().err


def test_the_default_prior_comes_from_the_package_share_never_the_working_directory(
        tmp_path: Path, prior_file: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    share = tmp_path / "share"
    (share / DEFAULT_PRIOR).parent.mkdir(parents=True)
    here = tmp_path / "cwd"
    (here / DEFAULT_PRIOR).parent.mkdir(parents=True)
    (here / DEFAULT_PRIOR).write_text("not a prior")
    (here / ENTRY_PRIOR).write_text("not a prior")
    monkeypatch.chdir(here)
    monkeypatch.setattr("fiper_ros.data_paths.package_share", lambda: share)
    args = argparse.Namespace(auto=True, auto_rule="transfer", auto_prior=None, auto_promise="entry")
    (share / ENTRY_PRIOR).write_text(prior_file.read_text())
    prior = prior_from(args, default=True)
    assert prior is not None and prior == Prior.load(prior_file)
    # with --auto-promise delta (the default) the prior ranked at that promise
    (share / DEFAULT_PRIOR).write_text(PRIOR_AT_DELTA.save(tmp_path / "delta.yaml").read_text())
    assert prior_from(argparse.Namespace(**{**vars(args), "auto_promise": "delta"}), default=True) == PRIOR_AT_DELTA
    assert prior_from(args, default=False) is None  # fiper evaluate: each task's prior of the run's other tasks
    monkeypatch.setattr("fiper_ros.data_paths.package_share", lambda: None)
    with pytest.raises(UsageError, match="give --auto-prior FILE"):
        prior_from(args, default=True)


def test_calibrate_auto_promise_entry_reads_the_shipped_prior_ranked_at_that_promise(
        tmp_path: Path, signal_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shipped = Prior.load(Path(__file__).resolve().parents[2] / ENTRY_PRIOR)  # the checkout's, installed in the share
    assert shipped.tasks == ("sorting", "stacking", "push_t") and len(shipped.entries) == 200
    assert shipped.selection["promise"] == "entry" and shipped.selection["statistic"] == "mean"
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "transfer", "--auto-promise",
                 "entry", "--delta", "0.3", "--seed", "2"]) == 0
    record = load_calibration(out).auto
    assert record["prior"]["content_hash"] == shipped.content_hash and record["settings"]["promise"] == "entry"
    assert record["chosen"] == shipped.entries[record["rank"] - 1].to_dict()
    assert all(skipped["why"] == "need a detector the successes cannot feed" for skipped in record["skipped"])


def test_calibrate_auto_rule_transfer_reads_the_shipped_prior_ranked_at_delta_by_default(
        tmp_path: Path, signal_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    shipped = Prior.load(Path(__file__).resolve().parents[2] / DEFAULT_PRIOR)  # installed in the share
    assert shipped.tasks == ("sorting", "stacking", "push_t") and len(shipped.entries) == 200
    assert shipped.selection["promise"] == "delta" and shipped.selection["statistic"] == "rank"
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "transfer", "--delta", "0.3",
                 "--seed", "2"]) == 0
    record = load_calibration(out).auto
    assert record["prior"]["content_hash"] == shipped.content_hash and record["settings"]["promise"] == "delta"
    assert not any(line.startswith("note:") for line in capsys.readouterr().out.splitlines())
