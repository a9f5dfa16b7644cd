"""Demonstration files: content, format and resumption."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sim_bridge.cli import main
from sim_bridge.demos import episode_path


def test_demos_cli_writes_and_resumes(tmp_path: Path) -> None:
    out = tmp_path / "stacking"
    assert main(["demos", "--task", "stacking", "--episodes", "1", "--out", str(out), "--seed", "7"]) == 0
    path = episode_path(out, 7)
    mtime = path.stat().st_mtime_ns
    with np.load(path) as data:
        steps = len(data["actions"])
        assert data["actions"].shape == (steps, 8) and data["actions"].dtype == np.float32
        assert data["proprio"].shape == (steps, 11)
        assert data["wrist_rgb"].shape == (steps, 96, 96, 3) and data["third_rgb"].dtype == np.uint8
        assert bool(data["success"]) and str(data["scenario"]) == "id" and int(data["seed"]) == 7
        assert int(data["horizon"]) == 8 and int(data["exec_steps"]) == 4
    assert main(["demos", "--task", "stacking", "--episodes", "2", "--out", str(out), "--seed", "7"]) == 0
    assert path.stat().st_mtime_ns == mtime
    assert episode_path(out, 8).exists()
    assert not list(out.glob("*.tmp.npz"))


def test_demos_cli_makes_every_task_from_one_command(tmp_path: Path) -> None:
    assert main(["demos", "--task", "all", "--episodes", "1", "--out", str(tmp_path), "--seed", "3"]) == 0
    for task, dim in (("sorting", 2), ("stacking", 8), ("pusht", 2)):
        with np.load(episode_path(tmp_path / task, 3)) as data:
            assert data["actions"].shape[1] == dim and bool(data["success"])
