"""Rollout records and their npz container."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.core_data import make_rollout

from fiper_ros.core.rollout import Rollout, RolloutError, RolloutSet


def _arrays(steps: int = 3) -> dict[str, np.ndarray]:
    return {"embeddings": np.zeros((steps, 4)), "actions": np.zeros((steps, 2, 5, 3))}


def test_properties() -> None:
    rollout = Rollout("a", "task", "id", exec_steps=2, success=True, **_arrays())
    assert rollout.length == 3 and not rollout.is_ood and rollout.failed is False
    assert rollout.embeddings.dtype == np.float32 and rollout.actions.dtype == np.float32
    assert Rollout("b", "task", "clutter", exec_steps=2, success=None, **_arrays()).is_ood


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"embeddings": np.zeros((4, 4))}, "T=4"),
        ({"actions": np.zeros((3, 2, 5))}, r"\[T, B, H, D\]"),
        ({"embeddings": np.full((3, 4), np.nan)}, "NaN"),
        ({"exec_steps": 6}, "exec_steps"),
        ({"action_space": "torque"}, "action_space"),
    ],
)
def test_validation(change: dict, message: str) -> None:
    fields = {"rollout_id": "x", "task": "t", "scenario": "id", "exec_steps": 2, "success": True, **_arrays()}
    fields.update(change)
    with pytest.raises(RolloutError, match=message):
        Rollout(**fields)


def test_npz_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    calibration = [make_rollout(rng, i) for i in range(2)]
    test = [make_rollout(rng, 5, ood=True, success=False)]
    test[0].metadata.update({"seed": 4, "joint_positions": rng.normal(size=(test[0].length, 7))})
    path = tmp_path / "rollouts.npz"
    RolloutSet(calibration, test).save_npz(path)
    loaded = RolloutSet.load_npz(path)
    assert [r.rollout_id for r in loaded.calibration] == ["id-0", "id-1"]
    again = loaded.test[0]
    assert np.array_equal(again.actions, test[0].actions) and np.array_equal(again.embeddings, test[0].embeddings)
    assert again.metadata["seed"] == 4
    assert np.array_equal(again.metadata["joint_positions"], test[0].metadata["joint_positions"])
    assert (again.success, again.scenario, again.exec_steps) == (False, "shift", 4)
    assert loaded.max_length() == max(r.length for r in calibration + test)


def test_npz_errors(tmp_path: Path) -> None:
    odd = make_rollout(np.random.default_rng(1), 0)
    odd.metadata["when"] = object()
    with pytest.raises(RolloutError, match="JSON"):
        RolloutSet([odd]).save_npz(tmp_path / "odd.npz")
    with pytest.raises(RolloutError, match="not found"):
        RolloutSet.load_npz(tmp_path / "none.npz")
    np.savez(tmp_path / "other.npz", x=np.zeros(2))
    with pytest.raises(RolloutError, match="__header__"):
        RolloutSet.load_npz(tmp_path / "other.npz")
    np.savez(tmp_path / "future.npz", __header__=np.array('{"format_version": 99, "splits": {}}'))
    with pytest.raises(RolloutError, match="format_version 99"):
        RolloutSet.load_npz(tmp_path / "future.npz")


def _signalled(**signals: object) -> Rollout:
    return Rollout("r7", "task", "id", exec_steps=2, success=True, signals=signals, **_arrays())  # type: ignore[arg-type]


def test_signals_are_float64_series_of_one_value_per_step() -> None:
    rollout = _signalled(chunk_mse=[1, 2, 3], eef_z2=np.array([0.5, 0.25, 0.125], np.float32))
    assert rollout.signals["chunk_mse"].dtype == np.float64 and rollout.signals["chunk_mse"].tolist() == [1, 2, 3]
    assert rollout.signals["eef_z2"].tolist() == [0.5, 0.25, 0.125]
    assert Rollout("r", "t", "id", exec_steps=2, success=True, **_arrays()).signals == {}


@pytest.mark.parametrize(("signals", "message"), [
    ({"chunk_mse": [1.0, np.nan, np.inf]}, r"rollout 'r7': signal 'chunk_mse' is NaN/inf at step 1 \(first\)"),
    ({"jerk": [0.0, 1.0, -np.inf]}, r"rollout 'r7': signal 'jerk' is NaN/inf at step 2 \(first\)"),
    ({"chunk_mse": [1.0, 2.0]}, r"rollout 'r7': signal 'chunk_mse' has shape \(2,\), expected \(3,\)"),
    ({"chunk_mse": np.zeros((3, 1))}, r"signal 'chunk_mse' has shape \(3, 1\), expected \(3,\)"),
    ({"chunk_mse": ["a", "b", "c"]}, "rollout 'r7': signal 'chunk_mse' is not numbers"),
    ({"Chunk": [1.0, 2.0, 3.0]}, r"rollout 'r7': signal name 'Chunk' must match \^\[a-z\]\[a-z0-9_\]\*\$"),
    ({"1st": [1.0, 2.0, 3.0]}, "signal name '1st' must match"),
    ({"chunk-mse": [1.0, 2.0, 3.0]}, "signal name 'chunk-mse' must match"),
    ({"chunk_mse\n": [1.0, 2.0, 3.0]}, "signal name 'chunk_mse\\\\n' must match"),
    ({"": [1.0, 2.0, 3.0]}, "signal name '' must match"),
])
def test_bad_signals_are_named(signals: dict, message: str) -> None:
    with pytest.raises(RolloutError, match=message):
        _signalled(**signals)


def test_signals_round_trip_through_npz_and_files_without_them_still_load(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    plain = make_rollout(rng, 0)
    signalled = make_rollout(rng, 1)
    signalled.signals = {"chunk_mse": rng.normal(size=signalled.length), "gripper_oscillation":
                         np.arange(signalled.length, dtype=np.float64)}
    signalled.__post_init__()
    path = tmp_path / "rollouts.npz"
    RolloutSet([plain], [signalled]).save_npz(path)
    loaded = RolloutSet.load_npz(path)
    assert loaded.calibration[0].signals == {}
    again = loaded.test[0].signals
    assert sorted(again) == ["chunk_mse", "gripper_oscillation"]
    assert all(np.array_equal(again[k], signalled.signals[k]) and again[k].dtype == np.float64 for k in again)
    with np.load(path) as data:
        assert "test/0/signals/chunk_mse" in data.files
    # a file of format version 1 written before signals existed: no "signals" in its headers
    old = tmp_path / "old.npz"
    header = {"format_version": 1, "splits": {"calibration": [{
        "rollout_id": "a", "task": "t", "scenario": "id", "exec_steps": 1, "success": True,
        "action_space": "ee_position", "metadata_arrays": [], "metadata": {}}], "test": []}}
    np.savez(old, __header__=np.array(json.dumps(header)), **{"calibration/0/embeddings": np.ones((2, 3))})
    (rollout,) = RolloutSet.load_npz(old).calibration
    assert rollout.signals == {} and rollout.embeddings.shape == (2, 3) and rollout.actions is None
