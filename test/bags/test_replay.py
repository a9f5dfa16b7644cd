"""``fiper replay`` through the real node processes over DDS (loopback) says exactly what the offline
oracle (bag -> Rollouts -> core.monitor.predict_rollout) says, step for step, on every sample bag."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from fiper_ros.bags.offline import predict_bag
from fiper_ros.bags.reader import BagReader, find_bags
from fiper_ros.core.calibration import load_calibration
from helpers.dds import ros_env

SAMPLES = Path(__file__).resolve().parents[2] / "bags"
SETS = sorted(p for p in SAMPLES.iterdir() if (p / "calibration").is_dir()) if SAMPLES.is_dir() else []


def _replay(args: list[str], domain: int, report: Path, timeout: float = 240) -> dict:
    result = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "replay", *args, "--domain", str(domain),
                             "--report", str(report)], env=ros_env(domain), capture_output=True, text=True,
                            timeout=timeout)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    return json.loads(report.read_text())


def _offline(bags: list[Path], calibration: Path) -> list[dict]:
    cal = load_calibration(calibration)
    return [r.to_dict() for bag in find_bags(bags) for r in predict_bag(bag, cal)]


def test_sample_sets_exist() -> None:
    assert [p.name for p in SETS] == ["pretzel_synthetic", "pushchair_synthetic", "sorting_sim"]
    size = sum(f.stat().st_size for f in SAMPLES.rglob("*") if f.is_file())
    assert size <= 30e6, f"bags/ holds {size / 1e6:.1f} MB"


#: How each sample set is played: as fast as the suite answers, and at a multiple of real time.
PACING = {"pretzel_synthetic": ["--fast"], "pushchair_synthetic": ["--rate", "25"], "sorting_sim": ["--fast"]}
#: Rollouts in each set's bags (calibration and test).
ROLLOUTS = {"pretzel_synthetic": 20, "pushchair_synthetic": 20, "sorting_sim": 9}


def _bag_seconds(bags: list[Path]) -> float:
    total = 0.0
    for bag in find_bags(bags):
        with BagReader(bag) as reader:
            total += (reader.end_ns - reader.start_ns) / 1e9
    return total


@pytest.mark.slow
@pytest.mark.parametrize("sample_set", SETS, ids=[p.name for p in SETS])
def test_live_replay_equals_offline_on_every_sample_bag(sample_set: Path, ros_domain: int, tmp_path: Path) -> None:
    pacing = PACING[sample_set.name]
    # Equality is the point here, not latency: a step whose alarm is late on a loaded machine must not
    # count as missing (the default --step-timeout is 5 s); a dropped alarm still does.
    report = _replay([str(sample_set), *pacing, "--step-timeout", "30"], ros_domain, tmp_path / "report.json")
    expected = _offline([sample_set], sample_set / "calibration")
    assert report["missing"] == []
    assert len(report["rollouts"]) == len(expected) == ROLLOUTS[sample_set.name]
    by_id = {r["rollout_id"]: r for r in expected}
    for live in report["rollouts"]:
        offline = by_id[live["rollout_id"]]
        assert live == offline, (live["rollout_id"], [(a, b) for a, b in zip(live["steps"], offline["steps"]) if a != b][:3])
    assert any(r["first_alarm"] is not None for r in expected)  # the failures are predicted
    if pacing[0] == "--rate":  # played on the bag's clock: no faster than bag time / rate
        assert report["seconds"] >= _bag_seconds([sample_set]) / float(pacing[1]) * 0.95
