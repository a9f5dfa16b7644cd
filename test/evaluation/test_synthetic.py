"""The SYNTHETIC generator: paper shapes, labelled, seeded, the four categories present."""

from __future__ import annotations

import numpy as np

from fiper_ros.evaluation.synthetic import TASKS, make_task


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
