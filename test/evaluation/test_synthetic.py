"""The SYNTHETIC generator: paper shapes, labelled, seeded, the four categories present."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_ros.evaluation.synthetic import TASKS, main, make_task


def test_shapes_labels_and_mix() -> None:
    rollouts = make_task("stacking", seed=1, calibration=5, test=20)
    spec = TASKS["stacking"]
    assert all(r.success and not r.is_ood for r in rollouts.calibration)
    for r in rollouts.calibration + rollouts.test:
        assert r.metadata["synthetic"] is True and r.rollout_id.startswith("synthetic-")
        assert r.actions.shape[1:] == (spec.samples, spec.horizon, spec.dims)
        assert r.embeddings.shape[1] == spec.embedding_dim and r.length <= spec.max_steps
    kinds = {(r.is_ood, r.success) for r in rollouts.test}
    assert kinds == {(False, True), (False, False), (True, True), (True, False)}
    again = make_task("stacking", seed=1, calibration=5, test=20)
    np.testing.assert_array_equal(again.test[3].actions, rollouts.test[3].actions)


def test_an_unknown_task_is_refused_as_a_flag(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """``python -m fiper_ros.evaluation.synthetic --tasks`` with a task it has no shapes for: argparse's refusal (exit
    2, the flag and the tasks it offers on one line), nothing written (was a ValueError's traceback)."""
    with pytest.raises(SystemExit) as exited:
        main(["--out", str(tmp_path / "out"), "--tasks", "sorting,folding"])
    assert exited.value.code == 2
    *_, last = capsys.readouterr().err.splitlines()
    assert last.endswith(f"error: --tasks: unknown 'folding'; expected some of {', '.join(TASKS)}")
    assert not (tmp_path / "out").exists()
