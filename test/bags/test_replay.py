"""``fiper replay`` through the real node processes over DDS (loopback) says exactly what the offline
oracle (bag -> Rollouts -> core.monitor.predict_rollout) says, step for step, on every sample bag; a step
without an alarm makes it exit 1. Its closing table (TPR, TNR, detection steps per scenario) on
``bags/sorting_sim`` is the one counted by hand from bags/README.md's table, live and offline; replaying the
calibration's own rollouts is said to be in-sample."""
from __future__ import annotations

import json
import subprocess
import sys
import zlib
from pathlib import Path

import numpy as np
import pytest
from helpers.dds import ros_env
from helpers.synthetic import FAIL_FROM, TINY_RND, make_rollout

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.client.replay import played_topics, readers_needed, suite_subscribers
from fiper_ros.core.calibration import CalibrationSettings, calibrate, load_calibration
from fiper_ros.core.detectors import DETECTORS, OBSERVATION_ONLY
from fiper_ros.core.rollout import Rollout
from fiper_ros.evaluation.offline import predict_bag
from fiper_ros.interface.messages import outcome_name
from fiper_ros.interface.topics import EMBEDDING_TOPIC, EVENTS_TOPIC, STEP_SIGNALS_TOPIC

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


#: ``bags/sorting_sim`` by hand, from the table of bags/README.md (outcome, first alarm step; failures run 75 steps):
#: id: success / none, failure / 18, success / none; box_pos: failure / 25, 21, 21; camera_moved: failure / 13, 12,
#: success (48 steps) / 20. DT = first alarm / 75 for every detected failure.
SORTING_VERDICTS = [
    {"scenario": "box_pos", "rollouts": 3, "unknown_outcome": 0, "failures": 3, "successes": 0, "tp": 3, "fn": 0,
     "tn": 0, "fp": 0, "tpr": 1.0, "tnr": None, "mean_detection_step": 67 / 3, "dt": 67 / 3 / 75},
    {"scenario": "camera_moved", "rollouts": 3, "unknown_outcome": 0, "failures": 2, "successes": 1, "tp": 2, "fn": 0,
     "tn": 0, "fp": 1, "tpr": 1.0, "tnr": 0.0, "mean_detection_step": 12.5, "dt": 12.5 / 75},
    {"scenario": "id", "rollouts": 3, "unknown_outcome": 0, "failures": 1, "successes": 2, "tp": 1, "fn": 0,
     "tn": 2, "fp": 0, "tpr": 1.0, "tnr": 1.0, "mean_detection_step": 18.0, "dt": 18 / 75},
    {"scenario": "all", "rollouts": 9, "unknown_outcome": 0, "failures": 6, "successes": 3, "tp": 6, "fn": 0,
     "tn": 2, "fp": 1, "tpr": 1.0, "tnr": 2 / 3, "mean_detection_step": 110 / 6, "dt": 110 / 6 / 75},
]
SORTING_TABLE = """\
verdicts on 9 rollouts with a known outcome (failures are positives: an alarm on a failure is a true positive):
scenario         rollouts failures  TPR           successes  TNR           mean detection step
box_pos                 3        3  1.00 (3/3)            0  -             22.3 (DT 0.30)
camera_moved            3        2  1.00 (2/2)            1  0.00 (0/1)    12.5 (DT 0.17)
id                      3        1  1.00 (1/1)            2  1.00 (2/2)    18.0 (DT 0.24)
all                     9        6  1.00 (6/6)            3  0.67 (2/3)    18.3 (DT 0.24)
"""


def _assert_sorting_verdicts(report: dict, stdout: str) -> None:
    """The report's table is the one by hand (to float rounding), printed as such, and the bags' END events say the
    outcomes it was counted from."""
    assert len(report["verdicts"]) == len(SORTING_VERDICTS)
    for row, expected in zip(report["verdicts"], SORTING_VERDICTS, strict=True):
        assert row == pytest.approx(expected), row["scenario"]
    assert SORTING_TABLE in stdout
    outcomes = {}
    for bag in find_bags([SAMPLES / "sorting_sim"]):
        with BagReader(bag) as reader:
            for message in reader.messages([EVENTS_TOPIC]):
                event = reader.decode(message)
                if event.event == RolloutEvent.EVENT_START:
                    scenario = event.scenario
                elif event.event == RolloutEvent.EVENT_END:
                    outcomes.setdefault(scenario, []).append(outcome_name(event.outcome))
    assert {k: sorted(v) for k, v in outcomes.items()} == {"id": ["failure", "success", "success"],
                                                           "box_pos": ["failure"] * 3,
                                                           "camera_moved": ["failure", "failure", "success"]}


def test_offline_replay_prints_the_verdicts_counted_by_hand(ros_domain: int, tmp_path: Path) -> None:
    report, result = _replay([str(SAMPLES / "sorting_sim"), "--offline"], ros_domain, tmp_path / "report.json")
    _assert_sorting_verdicts(report, result.stdout)
    assert "detected (true positive)" in result.stdout and "false alarm (false positive)" in result.stdout
    assert report["in_sample"] == [] and "in-sample" not in result.stderr  # its calibration records no split


def test_replaying_the_calibrations_own_rollouts_says_they_are_in_sample(
        observation_bags: dict[str, Path], observation_calibration: Path, ros_domain: int, tmp_path: Path) -> None:
    bags = [observation_bags["calibration"], observation_bags["test"]]  # ids 1..12 calibrated on, 21..23 not
    report, result = _replay([*map(str, bags), "--calibration", str(observation_calibration), "--offline"],
                             ros_domain, tmp_path / "report.json")
    assert report["in_sample"] == list(range(1, 13))
    assert ("fiper replay: warning: 12 of the 15 rollouts are the calibration's own (rollout 1, 2, 3, 4, 5, ...): it "
            "was fitted on them, so their verdicts are in-sample") in result.stderr
    report, result = _replay([str(bags[1]), "--calibration", str(observation_calibration), "--offline"],
                             ros_domain, tmp_path / "test.json")
    assert report["in_sample"] == [] and "warning" not in result.stderr


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
    report, result = _replay([str(sample_set), *pacing, "--step-timeout", "30"], ros_domain, tmp_path / "report.json")
    expected = _offline([sample_set], sample_set / "calibration")
    if sample_set.name == "sorting_sim":
        _assert_sorting_verdicts(report, result.stdout)
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
    assert all(len(s["windowed"]) == 1 for r in expected.values() for s in r["steps"])


def test_replay_exits_1_when_a_step_gets_no_alarm(small_calibration: Path, ros_domain: int, tmp_path: Path) -> None:
    """A bag recorded from after a rollout's START: the suite never fuses that rollout's steps (the fusion
    node waits for the START), so replay names each of them and exits 1; the complete rollout is answered."""
    whole, cut = tmp_path / "whole", tmp_path / "cut"
    write_rollouts(whole, [make_rollout(100, length=6), make_rollout(101, length=2)], [7, 8],
                   BagInfo(task="synthetic", synthetic=True, source="test"))
    with BagReader(whole) as reader, BagWriter(cut) as writer:
        writer.info = reader.info
        for message in reader.messages():
            if message.topic == EVENTS_TOPIC:
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


def test_the_step_signals_are_played_into_every_suite_without_waiting_for_a_reader() -> None:
    """No node of the suite reads ``/fiper/step_signals``: the player publishes them (to ``fiper record``, or a node
    of another's) but waits for no reader of them, in a suite it launched or one already running."""
    assert STEP_SIGNALS_TOPIC in played_topics(DETECTORS) and STEP_SIGNALS_TOPIC in played_topics(OBSERVATION_ONLY)
    assert suite_subscribers(DETECTORS)[STEP_SIGNALS_TOPIC] == 0 and suite_subscribers(DETECTORS)[EMBEDDING_TOPIC] == 1
    assert readers_needed([EMBEDDING_TOPIC, STEP_SIGNALS_TOPIC, EVENTS_TOPIC]) == {EMBEDDING_TOPIC: 1,
                                                                                   STEP_SIGNALS_TOPIC: 0,
                                                                                   EVENTS_TOPIC: 1}


def test_a_bag_with_step_signals_replays_as_the_offline_oracle(small_calibration: Path, ros_domain: int,
                                                               tmp_path: Path) -> None:
    rollouts = [make_rollout(110, length=5), make_rollout(111, fail=True)]
    for rollout in rollouts:
        rollout.signals = {"chunk_mse": np.linspace(0.0, 1.0, rollout.length), "eef_z": np.zeros(rollout.length)}
    bag = tmp_path / "signals"
    write_rollouts(bag, rollouts, [5, 6], BagInfo(task="synthetic", synthetic=True, source="test"))
    with BagReader(bag) as reader:
        assert STEP_SIGNALS_TOPIC in reader.topics
    report, _ = _replay([str(bag), "--calibration", str(small_calibration), "--fast", "--step-timeout", "30"],
                        ros_domain, tmp_path / "report.json")
    assert report["missing"] == []
    assert {r["rollout_id"]: r for r in report["rollouts"]} == {r["rollout_id"]: r for r in
                                                                _offline([bag], small_calibration)}


def _with_signal(rollout: Rollout) -> Rollout:
    """``rollout`` logging ``chunk_mse``: small and flat while it succeeds, rising once it drifts."""
    rng = np.random.default_rng(zlib.crc32(rollout.rollout_id.encode()))
    values = rng.uniform(0.0, 0.1, rollout.length)
    if not rollout.success:
        values[FAIL_FROM:] += np.linspace(0.5, 2.0, rollout.length - FAIL_FROM)
    rollout.signals = {"chunk_mse": values}
    return rollout


@pytest.mark.slow
@pytest.mark.parametrize(("detectors", "combine", "equalise", "threshold"), [
    (("rnd_oe", "progress", "elapsed", "signal_chunk_mse"), "max", "none", "cp_scaled"),
    (("rnd_oe", "ace", "consistency"), "kth:2", "none", "cp_scaled"),
    (("rnd_oe", "progress", "elapsed", "signal_chunk_mse"), "max", "quantile", "cp_scaled"),
    (("rnd_oe", "progress", "signal_chunk_mse"), "max", "none", "cp_constant"),
], ids=["four-detectors-max", "three-detectors-kth2", "four-detectors-max-tails-equalised",
        "three-detectors-max-constant-shapes"])
def test_an_n_detector_suite_replays_as_the_offline_oracle(detectors: tuple[str, ...], combine: str, equalise: str,
                                                           threshold: str, ros_domain: int, tmp_path: Path) -> None:
    """Live == offline for the combinations: a calibration of N detectors under one joint threshold (the detector
    nodes of every declared detector, the fusion node voting as the calibration says; the tails equalised or not;
    per-step or constant shapes) alarms on every step of a replayed bag exactly as the offline oracle does, and
    predicts the failure."""
    settings = CalibrationSettings(detectors=detectors, combine=combine, threshold=threshold, window=3, delta=0.2,
                                   rnd=TINY_RND, seed=0, equalise=equalise)
    calibration = tmp_path / "calibration"
    calibrate([_with_signal(make_rollout(400 + i)) for i in range(24)], settings).save(calibration)
    bag = tmp_path / "bag"
    rollouts = [_with_signal(make_rollout(500)), _with_signal(make_rollout(501, fail=True))]
    write_rollouts(bag, rollouts, [31, 32], BagInfo(task="synthetic", synthetic=True, source="test"))
    report, result = _replay([str(bag), "--calibration", str(calibration), "--fast", "--step-timeout", "30",
                              "--verbose"], ros_domain, tmp_path / "report.json")
    for detector in detectors:
        assert f"[launch] started {detector}_node" in result.stderr, detector
    expected = {r["rollout_id"]: r for r in _offline([bag], calibration)}
    assert report["missing"] == []
    assert {r["rollout_id"]: r for r in report["rollouts"]} == expected
    assert all(len(s["windowed"]) == len(detectors) for r in expected.values() for s in r["steps"])
    assert expected[32]["first_alarm"] is not None  # the failure is predicted
