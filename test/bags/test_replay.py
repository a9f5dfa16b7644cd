"""``fiper replay`` through the real node processes over DDS (loopback) says exactly what the offline
oracle (bag -> Rollouts -> core.monitor.predict_rollout) says, step for step, on every sample bag; a step
without an alarm makes it exit 1."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.dds import ros_env
from helpers.synthetic import make_rollout

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.core.calibration import load_calibration
from fiper_ros.evaluation.offline import predict_bag
from fiper_ros.interface.topics import EVENTS

SAMPLES = Path(__file__).resolve().parents[2] / "bags"
SETS = sorted(p for p in SAMPLES.iterdir() if (p / "calibration").is_dir()) if SAMPLES.is_dir() else []


def _replay(args: list[str], domain: int, report: Path, timeout: float = 240,
            status: int = 0) -> tuple[dict, subprocess.CompletedProcess[str]]:
    """Run ``fiper replay`` (asserting its exit ``status``); its JSON report and the finished process."""
    result = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "replay", *args, "--domain", str(domain),
                             "--report", str(report)], env=ros_env(domain), capture_output=True, text=True,
                            timeout=timeout)
    assert result.returncode == status, result.stdout[-3000:] + result.stderr[-3000:]
    return json.loads(report.read_text()), result


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
    report, _ = _replay([str(sample_set), *pacing, "--step-timeout", "30"], ros_domain, tmp_path / "report.json")
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


@pytest.mark.slow
def test_the_observation_only_suite_replays_as_the_offline_oracle(
        observation_bags: dict[str, Path], observation_calibration: Path, ros_domain: int, tmp_path: Path) -> None:
    """Issue #19 end to end: an observation-only calibration (``fiper calibrate --detectors rnd_oe``, the
    fixture) -> replay launches its suite (observation_only:=true: no ace_node, the fusion node on RND-OE alone) ->
    every step's alarm is the offline oracle's, for a bag without action batches and for one with them (they
    are not played: nothing in this suite reads them)."""
    bags = [observation_bags["test"], observation_bags["calibration_full"]]
    report, result = _replay([*map(str, bags), "--calibration", str(observation_calibration), "--fast",
                              "--step-timeout", "30", "--verbose"], ros_domain, tmp_path / "report.json")
    assert "[launch] started rnd_oe_node" in result.stderr and "[launch] started fusion_node" in result.stderr
    assert "ace_node" not in result.stderr and "fusing rnd_oe: alone, combine does not apply" in result.stderr
    expected = {r["rollout_id"]: r for r in _offline(bags, observation_calibration)}
    assert report["missing"] == [] and len(expected) == 3 + 12
    assert {r["rollout_id"]: r for r in report["rollouts"]} == expected
    assert [expected[i]["first_alarm"] is not None for i in (21, 22, 23)] == [False, True, False]  # failure predicted
    assert all(s["eta_act"] is None for r in expected.values() for s in r["steps"])


def test_replay_exits_1_when_a_step_gets_no_alarm(small_calibration: Path, ros_domain: int, tmp_path: Path) -> None:
    """A bag recorded from after a rollout's START: the suite never fuses that rollout's steps (the fusion
    node waits for the START), so replay names each of them and exits 1; the complete rollout is answered."""
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    write_rollouts(whole, [make_rollout(100, length=6), make_rollout(101, length=2)], [7, 8],
                   BagInfo(task="synthetic", synthetic=True, source="test"))
    with BagReader(whole) as reader, BagWriter(cut) as writer:
        writer.info = reader.info
        for message in reader.messages():
            if message.topic == EVENTS:
                event = reader.decode(message)
                if (event.rollout_id, event.event) == (8, RolloutEvent.EVENT_START):
                    continue
            writer.write(message.topic, message.log_time_ns, message.raw, message.msgtype)
    report, result = _replay([str(cut), "--calibration", str(small_calibration), "--fast", "--step-timeout", "5"],
                             ros_domain, tmp_path / "report.json", status=1)
    assert report["missing"] == [[8, 0], [8, 1]]
    for step in (0, 1):
        assert f"no alarm for rollout 8 step {step} within 5 s" in result.stderr
    assert "2 steps without an alarm" in result.stdout
    (complete,) = [r for r in report["rollouts"] if r["rollout_id"] == 7]
    assert len(complete["steps"]) == 6
