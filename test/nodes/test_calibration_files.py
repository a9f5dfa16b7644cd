"""The scoring nodes on a damaged calibration directory (every class of helpers.calibration_damage): both
stay alive and UNCONFIGURED, say why on /diagnostics in one line naming the file (the same line the
commands print), keep retrying, and configure once the directory is repaired (docs/reliability.md)."""
from __future__ import annotations

import shutil
from pathlib import Path

import pytest
from rclpy.parameter import Parameter

from helpers.calibration_damage import CALIBRATION_DAMAGES
from helpers.suite import Suite
from helpers.synthetic import make_rollout

SCORING_NODES = ("rnd_oe_node", "ace_node")
FAST = [Parameter("diagnostics_period_s", value=0.1), Parameter("configure_retry_s", value=0.2)]


def _status(suite: Suite, node: str) -> dict[str, str]:
    return suite.driver.diagnostics.get(f"fiper: /fiper/{node}", {})


def _configure_failed(suite: Suite, node: str) -> bool:
    return _status(suite, node).get("message", "").startswith("configure failed")


@pytest.mark.parametrize("damage", CALIBRATION_DAMAGES)
def test_a_scoring_node_on_a_damaged_calibration_stays_unconfigured_and_says_why(
        damage: str, ros_domain: int, calibration_dir: Path, tmp_path: Path) -> None:
    directory = tmp_path / "calibration"
    shutil.copytree(calibration_dir, directory)
    expected = f"configure failed: {CALIBRATION_DAMAGES[damage](directory)}"
    suite = Suite(ros_domain, str(directory), extra=FAST)
    try:
        for node in SCORING_NODES:
            assert suite.spin_until(lambda n=node: _configure_failed(suite, n)), (node, _status(suite, node))
            status = _status(suite, node)
            assert status["message"].startswith(expected) and "\n" not in status["message"], (node, status["message"])
            assert status["level"] == "2"  # DiagnosticStatus.ERROR
            assert status["lifecycle_state"] == "unconfigured"
        assert suite.rnd_oe.lifecycle_state() == suite.ace.lifecycle_state() == "unconfigured"
    finally:
        suite.close()


def test_a_repaired_calibration_is_loaded_on_the_next_retry(ros_domain: int, calibration_dir: Path,
                                                            tmp_path: Path) -> None:
    directory = tmp_path / "calibration"
    shutil.copytree(calibration_dir, directory)
    CALIBRATION_DAMAGES["yaml_edited"](directory)
    suite = Suite(ros_domain, str(directory), extra=FAST)
    try:
        assert suite.spin_until(lambda: all("content hash mismatch" in _status(suite, n).get("message", "")
                                            for n in SCORING_NODES))
        shutil.copy(calibration_dir / "calibration.yaml", directory / "calibration.yaml")
        suite.wait_active()
        assert suite.spin_until(lambda: all(_status(suite, n).get("message") == "running" for n in SCORING_NODES))
        rollout = make_rollout(402, length=4)
        alarms = suite.run(rollout, 5)
        assert sorted(alarms) == [0, 1, 2, 3]
    finally:
        suite.close()
