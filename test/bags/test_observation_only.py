"""Observation-only data through the commands (issue #19): bags without action batches are generated from
bags with them, read and written as rollouts without batches, refused by ``fiper calibrate`` in one line
unless it is asked for RND-OE alone (``--detectors rnd_oe``), and the observation-only calibration replays
(offline here; live over DDS in test_replay.py) and evaluates."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.synthetic import OBSERVATION_CALIBRATE, make_calibration

from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.cli import main
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import OBSERVATION_ONLY
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC


def test_an_observation_only_copy_keeps_every_other_message_byte_for_byte(observation_bags: dict[str, Path]) -> None:
    with BagReader(observation_bags["test_full"]) as full, BagReader(observation_bags["test"]) as copy:
        assert set(full.topics) == {EMBEDDING_TOPIC, ACTIONS_TOPIC,
                                    EVENTS_TOPIC} and set(copy.topics) == {EMBEDDING_TOPIC, EVENTS_TOPIC}
        kept = [(m.topic, m.log_time_ns, m.raw) for m in full.messages([EMBEDDING_TOPIC, EVENTS_TOPIC])]
        assert [(m.topic, m.log_time_ns, m.raw) for m in copy.messages()] == kept
        assert (copy.info.batch_size, copy.info.horizon, copy.info.action_dim, copy.info.action_space) == (0, 0, 0, "")
        assert copy.info.embedding_dim == full.info.embedding_dim and copy.info.split == "test"


def test_rollouts_without_action_batches_are_read_and_written_so(observation_bags: dict[str, Path],
                                                                   tmp_path: Path) -> None:
    full = read_rollouts(observation_bags["test_full"])
    rollouts = read_rollouts(observation_bags["test"])
    assert [r.actions for r in rollouts] == [None] * 3
    assert [r.exec_steps for r in rollouts] == [r.exec_steps for r in full]  # from custom_data
    write_rollouts(tmp_path / "again", rollouts, [21, 22, 23], BagInfo(task="synthetic", source="test"))
    with BagReader(tmp_path / "again") as bag:
        assert ACTIONS_TOPIC not in bag.topics and bag.info.action_space == ""
    again = read_rollouts(tmp_path / "again")
    assert all(np.array_equal(a.embeddings, b.embeddings) and b.actions is None for a, b in zip(full, again))
    assert [r.success for r in again] == [True, False, True]


def test_calibrate_without_action_batches_says_how_in_one_line(
        observation_bags: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bag = observation_bags["calibration"]
    assert main(["calibrate", str(bag), "-o", str(tmp_path / "cal"), "--max-epochs", "1"]) == 2
    err = capsys.readouterr().err
    assert err == (f"fiper calibrate: no action batches ({ACTIONS_TOPIC}) in {bag}: ACE cannot be calibrated; for an "
                   "observation-only calibration (RND-OE alone) give --detectors rnd_oe\n")
    assert not (tmp_path / "cal").exists()


def test_calibrate_rnd_oe_alone(observation_bags: dict[str, Path], observation_calibration: Path, tmp_path: Path,
                                capsys: pytest.CaptureFixture[str]) -> None:
    calibration = load_calibration(observation_calibration)
    assert calibration.detectors == OBSERVATION_ONLY and not calibration.layout.has_actions
    # the same options on the bag with action batches: the batches are not used, the calibration is the same
    out = tmp_path / "from_full"
    assert main(["calibrate", str(observation_bags["calibration_full"]), "-o", str(out), *OBSERVATION_CALIBRATE]) == 0
    printed = capsys.readouterr().out
    assert "judged by RND-OE alone (observation-only: no ACE)" in printed and "threshold RND-OE: cp_constant" in printed
    assert "ACE" not in printed.replace("R_d", "").replace("(observation-only: no ACE)", "")
    assert load_calibration(out).content_hash == calibration.content_hash


def test_offline_replay_judges_rnd_oe_alone(observation_bags: dict[str, Path], observation_calibration: Path,
                                           tmp_path: Path) -> None:
    report = tmp_path / "report.json"
    assert main(["replay", str(observation_bags["test"]), "--calibration", str(observation_calibration), "--offline",
                 "--report", str(report)]) == 0
    rollouts = {r["rollout_id"]: r for r in json.loads(report.read_text())["rollouts"]}
    assert rollouts[22]["outcome"] == "failure" and rollouts[22]["first_alarm"] is not None
    steps = [s for r in rollouts.values() for s in r["steps"]]
    assert all(len(s["exceeded"]) == len(s["windowed"]) == 1 and s["windowed"][0] is not None for s in steps)
    assert all((s["state"] == "alarm") == (s["step"] >= r["first_alarm"] if r["first_alarm"] is not None else False)
               for r in rollouts.values() for s in r["steps"])


def test_a_calibration_with_ace_on_a_bag_without_batches_is_refused_in_one_line(
        observation_bags: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    calibration = make_calibration(tmp_path / "pair")
    bag = observation_bags["test"]
    assert main(["replay", str(bag), "--calibration", str(calibration), "--offline"]) == 2
    assert capsys.readouterr().err == (
        f"fiper replay: calibration {calibration} declares rnd_oe, ace, but bag {bag} has no action batches for ACE: "
        "use an observation-only calibration (fiper calibrate --detectors rnd_oe)\n")


def test_evaluate_runs_the_methods_that_need_no_action_batches(
        observation_bags: dict[str, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    data = f"synthetic={observation_bags['calibration']},{observation_bags['test']}"
    common = ["evaluate", "--data", data, "--tiny", "--no-cache", "--quiet", "--no-plots", "--windows", "1-5",
              "--deltas", "0.1", "--split", "same"]
    assert main([*common, "--out", str(tmp_path / "all")]) == 0
    err = capsys.readouterr().err
    assert ("task(s) synthetic have no action batches (observation-only data); RND-A, STAC, ACE, FIPER, Consistency cannot run "
            "without them: evaluating Elapsed, PCA-kmeans, logpZO, RND-OE, Progress") in err
    results = json.loads((tmp_path / "all" / "results.json").read_text())
    assert results["settings"]["methods"] == ["elapsed", "pca_kmeans", "logpzo", "rnd_oe", "progress"]
    assert main([*common, "--methods", "rnd_oe,fiper", "--out", str(tmp_path / "fiper")]) == 2
    assert capsys.readouterr().err == (
        "fiper evaluate: task(s) synthetic have no action batches (observation-only data); FIPER cannot run without "
        "them: evaluate RND-OE (--methods rnd_oe)\n")
