"""The sample-set generator (`python -m fiper_ros.commands.samples`, docs/bags.md "Sample data")."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.commands import samples
from fiper_ros.core.calibration import CalibrationError

ROOT = Path(__file__).resolve().parents[2]


def test_the_pushchair_set_regenerates_the_shipped_rollouts(tmp_path: Path) -> None:
    """Its 10 calibration successes are calibrated on the same data on purpose: with #19's split default the
    command stopped with a +inf threshold (exit 2) and no set."""
    run = subprocess.run([sys.executable, "-m", "fiper_ros.commands.samples", "--sets", "pushchair", "--out", str(tmp_path)],
                         cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert run.returncode == 0, run.stderr[-2000:]
    made, shipped = tmp_path / "pushchair_synthetic", ROOT / "bags" / "pushchair_synthetic"
    for split in ("calibration_rollouts", "test_rollouts"):
        ours, theirs = read_rollouts(made / split), read_rollouts(shipped / split)
        assert len(ours) == len(theirs) == 10
        for a, b in zip(ours, theirs):
            assert np.array_equal(a.embeddings, b.embeddings) and np.array_equal(a.actions, b.actions)
            assert a.success == b.success
    calibration = yaml.safe_load((made / "calibration" / "calibration.yaml").read_text())
    assert calibration["settings"].get("split", "same") == "same"
    assert "not covered by Proposition 1" in calibration["guarantee"]


def test_a_calibration_the_core_refuses_is_one_line(monkeypatch: pytest.MonkeyPatch, tmp_path: Path,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    """A set whose calibration the core refuses (a CalibrationError, no longer relabelled a BagError by
    ``calibrate_bags``) is reported in one line, exit 2, as any user error of the sets."""
    def refused(*args: object, **kwargs: object) -> None:
        raise CalibrationError("a threshold is +inf:\n  too few conformal rollouts")

    monkeypatch.setattr(samples, "calibrate_bags", refused)
    assert samples.main(["--sets", "pushchair", "--out", str(tmp_path)]) == 2
    assert capsys.readouterr().err == "fiper samples: a threshold is +inf: too few conformal rollouts\n"
    assert not (tmp_path / "pushchair_synthetic").exists()
