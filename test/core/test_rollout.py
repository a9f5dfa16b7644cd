"""Rollout records and their npz container."""

from __future__ import annotations

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
