"""Observation-only through the live sim suite (issue #19): ``fiper demo`` and ``fiper collect --ros`` with a
calibration that declares RND-OE alone run the suite without an ACE node (sim bridge, policy node, RND-OE,
fusion and, in the demo, the supervisor, each its own process over loopback DDS), judge with RND-OE alone and
say so; the live alarms equal the offline oracle's on the data the runs recorded, step for step.

The calibration is made here by the project's own commands, as a user would: ``fiper collect`` of 8
successful in-distribution Sorting rollouts of the shipped policy (in-process, B = 4 for speed: RND-OE reads
the embeddings alone) and ``fiper calibrate --detectors rnd_oe`` on them (split conformal: RND-OE fitted on 4,
the CP-constant threshold on the other 4, delta 0.2). Measured with it on this machine: the demo's harmful OOD
rollout (box_pos seed 1000) crossed the threshold (31.0) at step 15 and peaked at 37.6 unhalted, the
in-distribution one (id seed 1002) at 26.8. The rollouts and the training are float32 numerics whose kernels
depend on the CPU: since this machine has AVX-512 (2026-12-02) the threshold is 35.7 and the OOD rollout crosses
it at step 29 (peak 37.4), so ``fiper collect --ros`` runs it for 40 steps.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from helpers.dds import ros_env
from helpers.demo_run import run_demo
from helpers.recorded_alarms import alarm_steps

from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.cli import main
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import OBSERVATION_ONLY
from fiper_ros.evaluation.offline import predict_bag
from fiper_ros.evaluation.results import StepResult
from fiper_ros.interface.topics import (ACTIONS_TOPIC, ALARM_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, SCORE_ACE_TOPIC,
                                        SCORE_RND_OE_TOPIC)

JUDGED_BY = "RND-OE alone (observation-only: no ACE)"
JUDGED = f"judged by {JUDGED_BY}"


@pytest.fixture(scope="module")
def observation_calibration(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """An observation-only calibration of the shipped Sorting policy, by ``fiper collect`` and ``fiper calibrate``."""
    root = tmp_path_factory.mktemp("observation_only")
    rollouts, calibration = root / "rollouts", root / "calibration"
    assert main(["collect", "--task", "sorting", "--successes", "8", "--max-episodes", "16", "--seed", "0",
                 "--batch", "4", "--split", "calibration", "--out", str(rollouts)]) == 0
    assert main(["calibrate", str(rollouts), "-o", str(calibration), "--detectors", "rnd_oe", "--threshold",
                 "cp_constant", "--window-obs", "8", "--delta", "0.2"]) == 0
    assert load_calibration(calibration).detectors == OBSERVATION_ONLY
    return calibration


def _oracle_agrees(bag: Path, calibration: Path, rollout_id: int, policy_steps: int) -> dict[int, StepResult]:
    """Assert that the alarms the fusion node published for ``rollout_id`` (as ``bag`` recorded them) are the
    offline oracle's on the same recorded data, step for step; the oracle's steps."""
    (offline,) = [r for r in predict_bag(bag, load_calibration(calibration)) if r.rollout_id == rollout_id]
    with BagReader(bag) as reader:
        recorded = alarm_steps(reader, rollout_id)
    assert len(offline.steps) == policy_steps
    # every step's decision is recorded (the very last one may follow the END past the bag's close)
    assert set(range(policy_steps - 1)) <= set(recorded) <= set(offline.steps)
    assert recorded == {step: offline.steps[step] for step in recorded}
    assert all(len(s.exceeded) == len(s.windowed) == 1 and s.windowed[0] is not None for s in recorded.values())
    return dict(offline.steps)


@pytest.mark.slow
def test_the_demo_runs_rnd_oe_alone_and_its_alarms_equal_the_offline_oracle(
        observation_calibration: Path, tmp_path: Path) -> None:
    out = tmp_path / "demo"
    run, summary = run_demo(out, "--calibration", str(observation_calibration))
    assert Path(summary["calibration"]) == observation_calibration
    assert summary["detectors"] == ["rnd_oe"] and summary["judged_by"] == JUDGED_BY
    log = (out / "suite.log").read_text()
    assert "[launch] started rnd_oe_node" in log and "[launch] started supervisor_node" in log
    assert "ace_node" not in log and "fusing rnd_oe: alone, combine does not apply" in log
    assert f"; {JUDGED} ..." in run.stdout and f"{JUDGED}; demo took" in run.stdout
    assert "| ACE" not in run.stdout and "| RND-OE" in run.stdout  # the progress lines show RND-OE alone
    with BagReader(out / "bag") as bag:
        topics = set(bag.topics)
    assert {EMBEDDING_TOPIC, ACTIONS_TOPIC, EVENTS_TOPIC, SCORE_RND_OE_TOPIC,
            ALARM_TOPIC} <= topics and SCORE_ACE_TOPIC not in topics
    calibration = load_calibration(observation_calibration)
    in_dist, ood = summary["rollouts"]
    for live in (in_dist, ood):
        # the trace holds the scores of RND-OE alone, every step scored
        assert live["detectors"] == ["rnd_oe"] and "ace" not in live and live["judged_by"] == JUDGED_BY
        assert live["outcome"] in ("success", "failure") and live["scored_steps"] == live["policy_steps"] > 0
        steps = _oracle_agrees(out / "bag", observation_calibration, live["rollout_id"], live["policy_steps"])
        assert min((t for t, s in steps.items() if s.state == "alarm"), default=None) == live["alarm_step"]
        assert np.array_equal(np.float32([steps[t].windowed[0] for t in sorted(steps)]),
                              np.float32(live["rnd_oe"]["windowed"]))
        assert np.array_equal(np.float32(live["rnd_oe"]["threshold"]),
                              np.float32(calibration.threshold("rnd_oe").over(live["policy_steps"])))
    # RND-OE alone alarms on the harmful OOD rollout and the supervisor halts the robot on it
    why = run.stdout[-2000:]
    assert ood["alarm_step"] is not None, why
    assert f"halting the robot (rollout {ood['rollout_id']}): ALARM" in log
    assert ood["alarm_step"] + 1 <= ood["policy_steps"] <= ood["alarm_step"] + 10
    for name in ("rollout_id_1002.png", "rollout_box_pos_1000.png"):  # a panel of RND-OE alone (test_trace.py)
        assert (out / name).read_bytes()[:4] == b"\x89PNG"


@pytest.mark.slow
def test_collect_ros_records_rnd_oe_alone_and_the_bag_replays(
        observation_calibration: Path, ros_domain: int, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out, steps = tmp_path / "collected", 40
    assert main(["collect", "--task", "sorting", "--scenarios", "box_pos", "--episodes", "1", "--seed", "1000",
                 "--max-policy-steps", str(steps), "--ros", "--calibration", str(observation_calibration),
                 "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"; {JUDGED} ..." in err and "ace_node" not in err
    index = json.loads((out / "collect.json").read_text())
    assert index["runs"][-1]["detectors"] == ["rnd_oe"]
    (entry,) = index["rollouts"]
    (bag,) = find_bags([out])
    with BagReader(bag) as reader:
        topics = set(reader.topics)
        calibration_hash = reader.info.calibration_hash
    assert {EMBEDDING_TOPIC, ACTIONS_TOPIC, EVENTS_TOPIC, SCORE_RND_OE_TOPIC,
            ALARM_TOPIC} <= topics and SCORE_ACE_TOPIC not in topics
    assert calibration_hash == load_calibration(observation_calibration).content_hash
    oracle = _oracle_agrees(bag, observation_calibration, entry["rollout_id"], steps)
    assert any(s.state == "alarm" for s in oracle.values())  # the OOD rollout is alarmed within its 40 steps
    # the bag replays through the observation-only suite (observation_only:=true) as the offline oracle says
    report = tmp_path / "report.json"
    replay = subprocess.run([sys.executable, "-m", "fiper_ros.cli", "replay", str(bag), "--calibration",
                             str(observation_calibration), "--fast", "--step-timeout", "30", "--domain",
                             str(ros_domain), "--report", str(report)], env=ros_env(ros_domain), capture_output=True,
                            text=True, timeout=240)
    assert replay.returncode == 0, replay.stdout[-3000:] + replay.stderr[-3000:]
    live = json.loads(report.read_text())
    offline = [r.to_dict() for r in predict_bag(bag, load_calibration(observation_calibration))]
    assert live["missing"] == [] and live["rollouts"] == offline
