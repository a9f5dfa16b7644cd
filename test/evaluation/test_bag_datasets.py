"""`fiper evaluate` reads bag folders (split by the bags' custom_data, or drawn per task for bags without a split) as
well as .npz rollout sets; data of several tasks is one dataset per task."""
from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.commands import evaluate
from fiper_ros.core.data_split import split_by_task
from fiper_ros.core.rollout import Rollout
from fiper_ros.evaluation.data import Dataset, DatasetError, load_dataset, load_datasets

BAGS = Path(os.environ["FIPER_ROOT"]) / "bags"


def test_sample_bags_load_with_their_calibration_and_test_splits() -> None:
    data = load_dataset("pushchair", [BAGS / "pushchair_synthetic"])
    assert len(data.calibration) == 10 and all(r.success for r in data.calibration)
    assert len(data.test) == 10 and {r.success for r in data.test} == {True, False}
    assert data.test[0].actions.shape[1:] == (256, 16, 3)


def test_a_folder_without_rollouts_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no .npz rollout files and no bags"):
        load_dataset("x", [tmp_path])


def _rollouts(task: str, successes: int, failures: int, seed: int) -> list[Rollout]:
    rng = np.random.default_rng(seed)
    return [Rollout(f"{task}-{i}", task, "id", rng.normal(size=(3, 4)), None, 1, i < successes,
                    signals={"chunk_mse": rng.normal(size=3)}) for i in range(successes + failures)]


def _bags(root: Path, groups: dict[str, list[Rollout]], split: str = "") -> None:
    next_id = 1
    for name, rollouts in groups.items():
        write_rollouts(root / name, rollouts, list(range(next_id, next_id + len(rollouts))),
                       BagInfo(task=rollouts[0].task, split=split))
        next_id += len(rollouts)


def test_bags_of_several_tasks_without_a_split_give_a_drawn_dataset_per_task(tmp_path: Path) -> None:
    """As ``fiper convert`` splits logs without a split: per task, a seeded fraction of its successes is calibration,
    every other rollout test; one dataset per task, named by the task."""
    groups = {"b/pick": _rollouts("pick", 12, 3, 1), "a/open": _rollouts("open", 16, 2, 2)}
    _bags(tmp_path, groups)
    datasets, drawn = load_datasets("mine", [tmp_path], fraction=0.7, seed=4)
    assert [d.task for d in datasets] == ["open", "pick"]
    assert [s.summary() for s in drawn.values()] == [  # in the order the bags are read
        "open: 18 rollouts (16 successes, 2 failures): calibration 11 successes, test 5 successes and 2 failures",
        "pick: 15 rollouts (12 successes, 3 failures): calibration 8 successes, test 4 successes and 3 failures"]
    for dataset in datasets:
        read = read_rollouts(tmp_path / ("a/open" if dataset.task == "open" else "b/pick"))
        expected = split_by_task(read, lambda r: r, 0.7, 4)[dataset.task]
        assert [r.rollout_id for r in dataset.calibration] == [r.rollout_id for r in expected.calibration]
        assert [r.rollout_id for r in dataset.test] == [r.rollout_id for r in expected.test]
        assert all(r.signals["chunk_mse"].shape == (3,) for r in dataset.test)
    again, _ = load_datasets("mine", [tmp_path], fraction=0.7, seed=4)
    other, _ = load_datasets("mine", [tmp_path], fraction=0.7, seed=5)
    assert [r.rollout_id for r in again[0].calibration] == [r.rollout_id for r in datasets[0].calibration]
    assert [r.rollout_id for r in other[0].calibration] != [r.rollout_id for r in datasets[0].calibration]
    # round(0.63 * 12) = 8 (0.62: 7)
    with pytest.raises(DatasetError, match=r"task 'pick': calibration fraction 0.5 draws 6 of its 12 successes; .* "
                                           "a fraction of 0.63 or more would do$"):
        load_datasets("mine", [tmp_path])


def test_one_task_keeps_the_name_given_and_split_bags_their_split(tmp_path: Path) -> None:
    _bags(tmp_path / "given", {"calibration": _rollouts("open", 4, 0, 3)}, split="calibration")
    _bags(tmp_path / "given", {"test": _rollouts("open", 1, 2, 4)}, split="test")
    datasets, drawn = load_datasets("drawer", [tmp_path / "given"])
    assert drawn == {} and [d.task for d in datasets] == ["drawer"]
    assert (len(datasets[0].calibration), len(datasets[0].test)) == (4, 3)
    _bags(tmp_path / "given", {"pick": _rollouts("pick", 4, 0, 5)}, split="calibration")
    _bags(tmp_path / "given", {"pick_test": _rollouts("pick", 1, 1, 6)}, split="test")
    assert [d.task for d in load_datasets("drawer", [tmp_path / "given"])[0]] == ["open", "pick"]
    with pytest.raises(DatasetError, match=r"^drawer: rollouts of 2 tasks \(open, pick\): one dataset per task"):
        load_dataset("drawer", [tmp_path / "given"])


def test_bags_with_and_without_a_split_are_refused(tmp_path: Path) -> None:
    _bags(tmp_path / "a", {"calibration": _rollouts("open", 10, 0, 5)}, split="calibration")
    _bags(tmp_path / "b", {"loose": _rollouts("open", 10, 2, 6)})
    with pytest.raises(DatasetError, match=f"^{tmp_path / 'b' / 'loose'}: no split \\(custom_data split empty\\), "
                                           f"while {tmp_path / 'a' / 'calibration'} has one: "):
        load_datasets("x", [tmp_path / "a", tmp_path / "b"])


def test_fiper_evaluate_prints_the_drawn_split(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _bags(tmp_path / "data", {"open": _rollouts("open", 16, 2, 2), "pick": _rollouts("pick", 12, 3, 1)})
    parser = argparse.ArgumentParser()
    evaluate.add_arguments(parser)
    args = parser.parse_args(["--data", f"mine={tmp_path / 'data'}", "--out", str(tmp_path / "out"),
                              "--calibration-fraction", "0.7", "--calibration-seed", "4"])
    assert [d.task for d in evaluate.datasets_from(args)] == ["open", "pick"]
    assert capsys.readouterr().out.splitlines() == [
        "fiper evaluate: mine: no split in the data: drawn per task with --calibration-fraction 0.7 "
        "--calibration-seed 4:",
        "  open: 18 rollouts (16 successes, 2 failures): calibration 11 successes, test 5 successes and 2 failures",
        "  pick: 15 rollouts (12 successes, 3 failures): calibration 8 successes, test 4 successes and 3 failures"]
    for bad, message in (("--calibration-fraction=0", r"--calibration-fraction: calibration fraction must be in "
                                                      r"\(0, 1\), got 0"),
                         ("--calibration-seed=-1", "--calibration-seed: the seed must be >= 0, got -1")):
        with pytest.raises(DatasetError, match=message):
            evaluate.datasets_from(parser.parse_args(["--data", "x=y", "--out", "o", bad]))


def test_the_score_cache_key_covers_the_signals_and_is_unchanged_without_them() -> None:
    def rollout(i: int, ok: bool, **signals: np.ndarray) -> Rollout:
        return Rollout(f"r{i}", "pick", "id", np.arange(6, dtype=np.float32).reshape(3, 2) + i, None, 1, ok,
                       signals=signals)

    def digest(**signals: np.ndarray) -> str:
        return Dataset("pick", [rollout(0, True)], [rollout(1, False, **signals), rollout(2, True)]).digest()

    # the digest of this data before signals existed (the code of commit 301d3c9)
    assert digest() == "49be7acbfdbacf7e0719b42d2e324a701ff50e11466d5d5229f18926dd1c0076"
    with_signal = digest(chunk_mse=np.array([0.0, 1.0, 2.0]))
    assert len({with_signal, digest(chunk_mse=np.array([0.0, 1.0, 2.5])), digest(eef_z=np.array([0.0, 1.0, 2.0])),
                digest()}) == 4
