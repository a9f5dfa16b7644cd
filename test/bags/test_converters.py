"""Converters on fixtures built here in the original layouts: FIPER rollout pickles and Sentinel episode
DataFrames -> one bag per split, read back as the same rollouts."""
from __future__ import annotations

import pickle
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas
import pytest
from helpers.converted import read_converted

from fiper_ros.bagio.errors import BagError
from fiper_ros.commands.convert import convert
from fiper_ros.converters.options import ConvertOptions

E, B, H = 12, 6, 8


def _steps(rng: np.random.Generator, length: int, dims: int) -> tuple[np.ndarray, np.ndarray]:
    return (rng.normal(size=(length, E)).astype(np.float32),
            rng.normal(size=(length, B, H, dims)).astype(np.float32))


def _fiper_fixture(root: Path) -> dict[str, tuple[str, str, bool, np.ndarray, np.ndarray]]:
    """<root>/pretzel/rollouts/{calibration,test}/*.pkl; returns file -> (split, scenario, success, emb, act)."""
    rng = np.random.default_rng(0)
    cases = {  # file name, split, metadata, expected scenario and success
        "rollout_000.pkl": ("calibration", {"successful": True, "rollout_subtype": "ca"}, "id", True),
        "rollout_001_s_.pkl": ("calibration", {}, "id", True),
        "rollout_002_success.pkl": ("test", {"rollout_subtype": "na"}, "id", True),
        "rollout_003_failure.pkl": ("test", {"rollout_subtype": "rope_rotation"}, "rope_rotation", False),
        "rollout_004_f_.pkl": ("test", {"rollout_subtype": "id"}, "id", False),
        "rollout_005_f_.pkl": ("test", {"successful": True, "rollout_subtype": "calibration"}, "id", True),
        "rollout_006.pkl": ("test", {"rollout_subtype": "rope_vertical"}, "rope_vertical", True),
    }
    expected = {}
    for i, (name, (split, metadata, scenario, success)) in enumerate(cases.items()):
        embeddings, actions = _steps(rng, 3 + i, 5)
        directory = root / "pretzel" / "rollouts" / split
        directory.mkdir(parents=True, exist_ok=True)
        steps = [{"obs_embedding": e[None], "action_pred": a, "action": a[0, 0], "rgb": np.zeros((2, 2, 3), np.uint8)}
                 for e, a in zip(embeddings, actions)]
        with (directory / name).open("wb") as stream:
            pickle.dump({"metadata": metadata, "rollout": steps}, stream)
        expected[f"{split}/{name}"] = (split, scenario, success, embeddings, actions)
    return expected


def _sentinel_fixture(root: Path, dims: int = 7) -> dict[str, tuple[str, str, bool, np.ndarray, np.ndarray]]:
    """<root>/push_chair/<date>_<code>/episodes/ep%04d.pkl DataFrames (timestep +4 per row)."""
    rng = np.random.default_rng(1)
    expected = {}
    for code, split, scenario in (("ca", "calibration", "id"), ("na", "test", "id"), ("hh", "test", "hh"),
                                  ("ss", "test", "ss")):
        for index, success in enumerate((True, code == "ca")):
            embeddings, actions = _steps(rng, 4 + index, dims)
            frame = pandas.DataFrame({"timestep": 100 + 4 * np.arange(len(embeddings)), "encoder_feat": list(embeddings),
                                      "sampled_actions": list(actions), "executed_action": [a[0] for a in actions],
                                      "success": success})
            directory = root / "push_chair" / f"2024-05-01_{code}" / "episodes"
            directory.mkdir(parents=True, exist_ok=True)
            frame.iloc[::-1].to_pickle(directory / f"ep{index:04d}.pkl")  # row order must not matter
            expected[f"2024-05-01_{code}/episodes/ep{index:04d}.pkl"] = (split, scenario, success, embeddings, actions)
    return expected


def test_fiper_pickles(tmp_path: Path) -> None:
    expected = _fiper_fixture(tmp_path / "src")
    counts = convert("fiper", tmp_path / "src" / "pretzel", tmp_path / "out", ConvertOptions(max_steps=70))
    assert counts.bags == {"calibration_rollouts": 2, "test_rollouts": 5}
    converted = read_converted(tmp_path / "out")
    assert sorted(converted) == sorted(expected)
    for name, (split, scenario, success, embeddings, actions) in expected.items():
        bag_split, rollout = converted[name]
        assert (bag_split, rollout.scenario, rollout.success, rollout.task) == (split, scenario, success, "pretzel"), name
        assert rollout.exec_steps == 8  # the paper's h of Pretzel
        assert np.array_equal(rollout.embeddings, embeddings) and np.array_equal(rollout.actions, actions)
    ids = sorted(int(r.rollout_id) for _, r in converted.values())
    assert ids == list(range(1, 8))


def test_sentinel_dataframes_default_pushchair_channels(tmp_path: Path) -> None:
    expected = _sentinel_fixture(tmp_path / "src")
    convert("sentinel", tmp_path / "src" / "push_chair", tmp_path / "out", ConvertOptions())
    converted = read_converted(tmp_path / "out")
    assert sorted(converted) == sorted(expected)
    for name, (split, scenario, success, embeddings, actions) in expected.items():
        bag_split, rollout = converted[name]
        assert (bag_split, rollout.scenario, rollout.success, rollout.task) == (split, scenario, success, "push_chair")
        assert rollout.exec_steps == 4  # from the timestep column
        assert np.array_equal(rollout.embeddings, embeddings)
        assert np.array_equal(rollout.actions, actions[..., 1:4])  # D = 7: the positions, channels 1-3


def test_sentinel_channel_option(tmp_path: Path) -> None:
    expected = _sentinel_fixture(tmp_path / "src")
    convert("sentinel", tmp_path / "src" / "push_chair", tmp_path / "all", ConvertOptions(channels="all"))
    convert("sentinel", tmp_path / "src" / "push_chair", tmp_path / "two", ConvertOptions(channels=(0, 2)))
    for name, (*_, actions) in expected.items():
        assert np.array_equal(read_converted(tmp_path / "all")[name][1].actions, actions)
        assert np.array_equal(read_converted(tmp_path / "two")[name][1].actions, actions[..., 0:2])


def test_bad_source_is_refused_and_nothing_is_written(tmp_path: Path) -> None:
    _sentinel_fixture(tmp_path / "src")
    bad = tmp_path / "src" / "push_chair" / "2024-05-01_na" / "episodes" / "ep0007.pkl"
    pandas.DataFrame({"timestep": [0], "success": [True]}).to_pickle(bad)
    with pytest.raises(BagError, match=r"ep0007.pkl: missing column\(s\) encoder_feat, sampled_actions"):
        convert("sentinel", tmp_path / "src" / "push_chair", tmp_path / "out", ConvertOptions())
    assert not (tmp_path / "out").exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    bad.write_bytes(b"not a pickle")
    result = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "convert", "sentinel",
                             str(tmp_path / "src" / "push_chair"), "-o", str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.count("\n") == 1 and "ep0007.pkl: not a readable pickle" in result.stderr
    assert "Traceback" not in result.stderr and not (tmp_path / "out").exists()


def test_unknown_split_code_is_named(tmp_path: Path) -> None:
    directory = tmp_path / "src" / "chair" / "misc" / "episodes"
    directory.mkdir(parents=True)
    (directory / "ep0000.pkl").write_bytes(b"")
    with pytest.raises(BagError, match="no split code"):
        convert("sentinel", tmp_path / "src" / "chair", tmp_path / "out", ConvertOptions())


def test_max_mb_refuses_a_pickle_before_unpickling_it(tmp_path: Path) -> None:
    """The bound is checked on the file's size: a 2 MB file that is no pickle is refused for its size."""
    _fiper_fixture(tmp_path / "src")
    big = tmp_path / "src" / "pretzel" / "rollouts" / "test" / "zz_big.pkl"
    big.write_bytes(b"x" * 2_000_000)
    with pytest.raises(BagError, match=r"zz_big.pkl: 2.0 MB on disk, with 0.\d MB converted before, exceeds --max-mb 1$"):
        convert("fiper", tmp_path / "src" / "pretzel", tmp_path / "out", ConvertOptions(max_mb=1))
    assert not (tmp_path / "out").exists()
