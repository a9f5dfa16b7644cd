"""Detector model files (core/detector_model.py): JSON + npz written and read back exactly; a damaged, modified,
swapped or foreign file is refused in one line naming it; nothing is unpickled."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.core.detector_model import ModelFileError, model_digest, read_model, write_model

ARRAYS = {"scale": np.array([1.0, 2.5]), "index": np.arange(6, dtype=np.int64).reshape(2, 3)}
DESCRIPTION = {"settings": {"floor": 0.1, "dims": [0, 2]}, "seed": 3}


def written(directory: Path) -> Path:
    write_model(directory, "toy", 1, DESCRIPTION, ARRAYS)
    return directory


def test_round_trip_and_digest(tmp_path: Path) -> None:
    meta, arrays = read_model(written(tmp_path), "toy", 1)
    assert meta == DESCRIPTION
    assert arrays.keys() == ARRAYS.keys()
    for name, array in ARRAYS.items():
        assert arrays[name].dtype == array.dtype and np.array_equal(arrays[name], array)
    content = json.loads((tmp_path / "toy.json").read_text())
    assert content["digest"] == model_digest("toy", 1, DESCRIPTION, ARRAYS)
    assert content["arrays"] == {"index": {"dtype": "<i8", "shape": [2, 3]}, "scale": {"dtype": "<f8", "shape": [2]}}
    changed = {**ARRAYS, "scale": np.array([1.0, 2.5000000000000004])}
    assert model_digest("toy", 1, DESCRIPTION, changed) != content["digest"]
    assert model_digest("toy", 1, {**DESCRIPTION, "seed": 4}, ARRAYS) != content["digest"]


def _edit_json(path: Path, change: Callable[[dict], None]) -> None:
    content = json.loads(path.read_text())
    change(content)
    path.write_text(json.dumps(content))


DAMAGES: dict[str, tuple[Callable[[Path], None], str]] = {
    "a modified setting": (lambda d: _edit_json(d / "toy.json", lambda c: c.update(seed=4)), "digest mismatch"),
    "another version": (lambda d: _edit_json(d / "toy.json", lambda c: c.update(format_version=2)),
                        "format_version 2 not supported"),
    "another kind": (lambda d: _edit_json(d / "toy.json", lambda c: c.update(kind="other")), "not a toy model"),
    "swapped arrays": (lambda d: np.savez(d / "toy.npz", scale=np.array([1.0, 2.0]), index=ARRAYS["index"]),
                       "digest mismatch"),
    "an extra array": (lambda d: np.savez(d / "toy.npz", **ARRAYS, extra=np.zeros(1)), "not the arrays"),
    "another shape": (lambda d: np.savez(d / "toy.npz", scale=np.zeros(3), index=ARRAYS["index"]),
                      r"expected float64 \(2,\)"),
    "a larger member": (lambda d: np.savez(d / "toy.npz", scale=np.zeros(1000), index=ARRAYS["index"]),
                        "larger than its described"),
    "pickled objects": (lambda d: np.savez(d / "toy.npz", scale=np.array([None, 1.0], dtype=object),
                                           index=ARRAYS["index"]), "pickle"),
    "a truncated archive": (lambda d: (d / "toy.npz").write_bytes((d / "toy.npz").read_bytes()[:50]), "unreadable"),
    "a json that does not parse": (lambda d: (d / "toy.json").write_text("{"), "unreadable"),
    "a missing file": (lambda d: (d / "toy.npz").unlink(), "model file missing"),
}


@pytest.mark.parametrize("damage", DAMAGES)
def test_damaged_files_are_refused_in_one_line(damage: str, tmp_path: Path) -> None:
    apply, message = DAMAGES[damage]
    apply(written(tmp_path))
    with pytest.raises(ModelFileError, match=message) as error:
        read_model(tmp_path, "toy", 1)
    assert str(tmp_path) in str(error.value) and "\n" not in str(error.value)
