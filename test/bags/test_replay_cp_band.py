"""The paper's default threshold, the one-sided CP band (App. A.3), through the real node processes over
DDS: ``fiper calibrate --threshold cp_band`` on a sample set's calibration bags, then ``fiper replay`` of its
test bags says exactly what the offline oracle says, step for step."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.dds import run_python

from fiper_ros.bagio.reader import find_bags
from fiper_ros.core.calibration import load_calibration
from fiper_ros.evaluation.offline import predict_bag

PRETZEL = Path(__file__).resolve().parents[2] / "bags" / "pretzel_synthetic"


def _fiper(args: list[str], domain: int, timeout: float = 300) -> None:
    result = run_python(["-m", "fiper_ros.cli", *args], domain, timeout)
    assert result.returncode == 0, result.stdout[-3000:]


@pytest.mark.slow
def test_live_replay_with_a_cp_band_calibration_equals_offline(ros_domain: int, tmp_path: Path) -> None:
    calibration_dir = tmp_path / "cp_band"
    # M = 10 successes split 5 / 5: ceil(6 (1 - delta)) <= 5 needs delta >= 1/6, so delta = 0.2.
    _fiper(["calibrate", str(PRETZEL / "calibration_rollouts"), "-o", str(calibration_dir), "--threshold", "cp_band",
            "--delta", "0.2", "--max-epochs", "30"], ros_domain)
    calibration = load_calibration(calibration_dir)
    for threshold in (calibration.threshold("rnd_oe"), calibration.threshold("ace")):
        assert threshold.kind == "cp_band" and np.isfinite(threshold.values).all()
        assert np.unique(threshold.values).size > 10, "a band: gamma_t = mu(t) + k s(t) moves with t"
    report_path = tmp_path / "report.json"
    _fiper(["replay", str(PRETZEL / "test_rollouts"), "--calibration", str(calibration_dir), "--fast",
            "--step-timeout", "30", "--domain", str(ros_domain), "--report", str(report_path)], ros_domain)
    report = json.loads(report_path.read_text())
    expected = {r.rollout_id: r.to_dict() for bag in find_bags([PRETZEL / "test_rollouts"])
                for r in predict_bag(bag, calibration)}
    assert report["missing"] == []
    assert sorted(r["rollout_id"] for r in report["rollouts"]) == sorted(expected)
    for live in report["rollouts"]:
        assert live == expected[live["rollout_id"]], live["rollout_id"]
    assert any(r["first_alarm"] is not None for r in expected.values())  # the band catches failures
    assert any(r["first_alarm"] is None for r in expected.values())
