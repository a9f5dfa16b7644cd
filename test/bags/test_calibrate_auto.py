"""``fiper calibrate --auto``: on a bag of successes (and a failure it never needs), it chooses the configuration from
the successes alone, prints the best candidates and why the winner won, and stores the choice in the calibration;
the same choice as :func:`fiper_ros.core.calibration.auto.auto_calibrate` with the same settings."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.cli import main
from fiper_ros.core.auto import AutoSettings
from fiper_ros.core.calibration import CalibrationSettings, load_calibration
from fiper_ros.core.calibration.auto import auto_calibrate
from fiper_ros.core.rollout import Rollout


def _rollout(index: int, *, fail: bool = False) -> Rollout:
    """A success whose logged signals a and b are flat and noisy (a failure: b jumps at step 10)."""
    rng = np.random.default_rng(index)
    length = 20
    signals = {"a": 1.0 + 0.1 * rng.random(length), "b": 1.0 + 0.1 * rng.random(length)}
    if fail:
        signals["b"][10:] += 20.0
    return Rollout(f"r{index}", "synthetic", "id", rng.normal(size=(length, 4)).astype(np.float32), None, 1,
                   not fail, signals=signals)


@pytest.fixture(scope="module")
def signal_bag(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("auto") / "bag"
    rollouts = [*(_rollout(i) for i in range(12)), _rollout(50, fail=True)]
    write_rollouts(path, rollouts, list(range(1, len(rollouts) + 1)),
                   BagInfo(task="synthetic", synthetic=True, source="test"))
    return path


def test_calibrate_auto_prints_and_stores_its_choice(tmp_path: Path, signal_bag: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--detectors", "signal_a,signal_b,elapsed",
                 "--auto-windows", "1,3", "--auto-folds", "3", "--delta", "0.3", "--seed", "2"]) == 0
    printed = capsys.readouterr().out
    calibration = load_calibration(out)
    record = calibration.auto
    assert record["rule"] == "proxy-twa" and record["detectors"] == ["elapsed", "signal_a", "signal_b"]
    assert list(calibration.settings.detectors) == record["chosen"]["detectors"]
    assert calibration.settings.shape_folds == 3 and calibration.num_rollouts == 12  # the failure is not used
    lines = printed.splitlines()
    head = lines.index(next(line for line in lines if line.startswith("auto (proxy-twa v1, delta 0.3): ")))
    assert lines[head + 1].split() == ["rank", "proxy", "TWA", "held-out", "FA", "stall", "drift", "skip",
                                       "candidate"]
    assert lines[head + 2].split()[0] == "1" and lines[head + 2].endswith(record["top"][0]["candidate"])
    assert f"chosen: {record['why']}" in lines
    settings = CalibrationSettings(detectors=("rnd_oe", "ace"), delta=0.3, seed=2)
    again, _ = auto_calibrate(read_rollouts(signal_bag), settings, AutoSettings(windows=(1, 3), folds=3),
                              ("signal_a", "signal_b", "elapsed"))
    assert again.auto == record and again.content_hash == calibration.content_hash


def test_calibrate_auto_refuses_a_budget_it_would_exceed(tmp_path: Path, signal_bag: Path,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--detectors", "signal_a,elapsed",
                 "--auto-budget", "3", "--delta", "0.3"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "exceed the auto budget of 3 (--auto-budget)" in err
    assert not out.exists()


def test_calibrate_auto_rule_margin_prints_and_stores_its_margins(tmp_path: Path, signal_bag: Path,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "calibration"
    assert main(["calibrate", str(signal_bag), "-o", str(out), "--auto", "--auto-rule", "margin", "--detectors",
                 "signal_a,signal_b,elapsed", "--auto-windows", "1,3", "--auto-folds", "3", "--delta", "0.3",
                 "--seed", "2"]) == 0
    lines = capsys.readouterr().out.splitlines()
    record = load_calibration(out).auto
    assert record["rule"] == "margin" and record["settings"]["rule"] == "margin"
    head = lines.index(next(line for line in lines if line.startswith("auto (margin v1, delta 0.3): ")))
    assert lines[head + 1].split() == ["rank", "margin", "held-out", "FA", "candidate"]
    first = lines[head + 2].split()
    assert first[0] == "1" and float(first[1]) == pytest.approx(record["top"][0]["figures"]["margin"], abs=1e-3)
    assert "elapsed" not in record["chosen"]["detectors"]  # no spread: an infinite margin
