"""`fiper evaluate` reads bag folders (split by the bags' custom_data) as well as .npz rollout sets."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

from fiper_ros.evaluation.data import DatasetError, load_dataset

BAGS = Path(os.environ["FIPER_ROOT"]) / "bags"


def test_sample_bags_load_with_their_calibration_and_test_splits() -> None:
    data = load_dataset("pushchair", [BAGS / "pushchair_synthetic"])
    assert len(data.calibration) == 10 and all(r.success for r in data.calibration)
    assert len(data.test) == 10 and {r.success for r in data.test} == {True, False}
    assert data.test[0].actions.shape[1:] == (256, 16, 3)


def test_a_folder_without_rollouts_is_a_clear_error(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no .npz rollout files and no bags"):
        load_dataset("x", [tmp_path])
