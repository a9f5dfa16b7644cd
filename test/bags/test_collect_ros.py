"""``fiper collect --ros``: the episodes through the live suite (sim bridge, policy node, RND-OE, ACE and fusion
as separate processes over loopback DDS), one bag per rollout recorded from DDS.

One ``--ros`` collect (2 short Sorting episodes: the shipped model with B = 4 and 3 policy steps, with the
shipped calibration) serves the whole module; the rest needs no suite: a rerun finds every bag and
starts none, and a run of the other kind is refused before anything starts.
"""
from __future__ import annotations

import json
import shutil
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from helpers.recorded_alarms import alarm_steps
from sim_bridge.closed_loop import run_episode

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import read_rollouts
from fiper_ros.cli import main
from fiper_ros.client import live_collect as collect_ros
from fiper_ros.client.live_collect import SOURCE, WORK_DIR
from fiper_ros.commands.collect import bag_name
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.detectors import DETECTORS, OBSERVATION_ONLY
from fiper_ros.evaluation.offline import predict_bag
from fiper_ros.interface.conversions import stamp_ns
from fiper_ros.interface.topics import (ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC, JOINT_STATES_TOPIC,
                                        SCORE_ACE_TOPIC, SCORE_RND_OE_TOPIC)
from fiper_ros.policy.policy import Policy
from helpers.launch import node_entry, write_launch

MODELS = Path(__file__).resolve().parents[2] / "models"
CALIBRATION = MODELS / "sorting" / "calibration"
SEEDS = (1000, 1001)
STEPS = 3


def collect_args(episodes: int = len(SEEDS)) -> list[str]:
    """``fiper collect`` of short Sorting id episodes from seed 1000 (without ``--out`` and the runner)."""
    return ["collect", "--task", "sorting", "--episodes", str(episodes), "--seed", str(SEEDS[0]), "--batch", "4",
            "--max-policy-steps", str(STEPS)]


@pytest.fixture(scope="module")
def collected(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Sorting id seeds 1000 and 1001 collected through the live suite, with scores and alarms."""
    out = tmp_path_factory.mktemp("collect_ros") / "sorting"
    assert main([*collect_args(), "--ros", "--calibration", str(CALIBRATION), "--out", str(out)]) == 0
    return out


def test_each_rollout_is_a_bag_of_the_live_run_equal_to_the_in_process_episode(collected: Path) -> None:
    assert sorted(p.name for p in collected.iterdir()) == ["collect.json", "id"]  # no lock, no work folder left
    bags = find_bags([collected])
    assert [b.relative_to(collected).as_posix() for b in bags] == [f"id/{bag_name('sorting', 'id', s)}" for s in SEEDS]
    index = json.loads((collected / "collect.json").read_text())
    assert (index["runner"], index["batch"], index["max_policy_steps"]) == ("ros", 4, STEPS)
    entries = {entry["seed"]: entry for entry in index["rollouts"]}
    policy = Policy.load(MODELS / "sorting")
    calibration = load_calibration(CALIBRATION)
    for seed, bag in zip(SEEDS, bags):
        entry = entries[seed]
        rollout_id = entry["rollout_id"]
        assert rollout_id & 0xFFFFFFFF == seed and rollout_id >> 32 >= 1  # the bridge's id: reset counter, seed
        with BagReader(bag) as reader:
            counts = Counter(m.topic for m in reader.messages())
            events = [reader.decode(m) for m in reader.messages([EVENTS_TOPIC])]
            info = reader.info
            recorded = alarm_steps(reader, rollout_id)
        assert counts[EMBEDDING_TOPIC] == counts[ACTIONS_TOPIC] == STEPS
        assert [(e.rollout_id, e.event, e.outcome, e.task, e.scenario, e.max_steps) for e in events] == [
            (rollout_id, RolloutEvent.EVENT_START, RolloutEvent.OUTCOME_UNKNOWN, "sorting", "id", STEPS),
            (rollout_id, RolloutEvent.EVENT_END, RolloutEvent.OUTCOME_FAILURE, "", "", 0)]
        # a scoring node drops a step that arrives after the END it saw: the last step's scores may be missing
        assert counts[SCORE_RND_OE_TOPIC] >= STEPS - 1 and counts[SCORE_ACE_TOPIC] >= STEPS - 1
        assert set(range(STEPS - 1)) <= set(recorded)
        assert (info.source, info.seed, info.split, info.task, info.policy) == (SOURCE, str(seed), "test", "sorting",
                                                                                "models/sorting")
        assert (info.batch_size, info.horizon, info.action_dim, info.exec_steps, info.embedding_dim) == (4, 8, 2, 4, 128)
        assert info.calibration_hash == calibration.content_hash and info.policy_hash == index["policy_hash"]
        # the live rollout is the in-process episode of the seed, bit for bit
        (rollout,) = read_rollouts(bag)
        episode = run_episode(policy, "id", seed, batch=4, max_policy_steps=STEPS)
        assert episode.rollout is not None
        np.testing.assert_array_equal(rollout.embeddings, episode.rollout.embeddings)
        np.testing.assert_array_equal(rollout.actions, episode.rollout.actions)
        assert (rollout.success, entry["success"]) == (episode.success, episode.success) == (False, False)
        assert (entry["policy_steps"], entry["control_steps"]) == (episode.policy_steps, episode.control_steps)
        # the alarms the fusion node published are those of the offline oracle on the recorded data
        (offline,) = predict_bag(bag, calibration)
        assert offline.rollout_id == rollout_id and len(offline.steps) == STEPS
        assert recorded == {step: offline.steps[step] for step in recorded}


def test_a_rerun_skips_every_finished_bag_without_starting_the_suite(
        collected: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sorting"
    shutil.copytree(collected, out)
    before = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert main([*collect_args(), "--ros", "--calibration", str(CALIBRATION), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("bag exists, skipped") == len(SEEDS) and "starting" not in err
    after = {p: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    assert after.keys() == before.keys() and all(after[p] == before[p] for p in before if p.name != "collect.json")
    assert not (out / WORK_DIR).exists()


def test_a_folder_of_the_other_runner_is_refused(collected: Path, tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    in_process = tmp_path / "in_process"
    assert main([*collect_args(1), "--out", str(in_process)]) == 0
    capsys.readouterr()

    def refused(*args: str) -> str:
        assert main(list(args)) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("fiper collect: ")
        return err

    err = refused(*collect_args(), "--ros", "--out", str(in_process))
    assert f"{in_process / 'collect.json'}: the folder was collected with other settings (runner 'in-process' != " \
           "'ros', folder != this run)" in err
    assert "(runner 'ros' != 'in-process', folder" in refused(*collect_args(), "--out", str(collected))
    # an index from before --ros (no runner key) is an in-process folder
    index = json.loads((in_process / "collect.json").read_text())
    del index["runner"]
    (in_process / "collect.json").write_text(json.dumps(index))
    assert "(runner 'in-process' != 'ros', folder" in refused(*collect_args(), "--ros", "--out", str(in_process))
    assert main([*collect_args(1), "--out", str(in_process)]) == 0
    assert "bag exists, skipped" in capsys.readouterr().err
    assert "--calibration runs the scoring nodes: it needs --ros" in refused(
        *collect_args(), "--calibration", str(CALIBRATION), "--out", str(tmp_path / "z"))
    assert not (tmp_path / "z").exists()


def test_a_node_that_dies_ends_the_collect_with_one_line_and_keeps_its_output(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    # both nodes die at start: a text where their parameter is an integer
    broken = write_launch(tmp_path / "broken.launch.yaml", {"arg": {"name": "model"}},
                          node_entry("bridge_node", {"seed": "'not a number'"}, package="sim_bridge", namespace="/sim"),
                          node_entry("policy_node", {"model": "$(var model)", "batch": "'not a number'"}))
    monkeypatch.setattr(collect_ros, "installed_launch", lambda name: broken)
    out = tmp_path / "sorting"
    assert main([*collect_args(), "--ros", "--out", str(out)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err[-1].startswith("fiper collect: the suite's launcher exited (") and "exited with code 1" in err[-1]
    assert err[-1].endswith(f"the nodes' output: {out / WORK_DIR / 'suite.log'}")
    assert "InvalidParameterTypeException" in (out / WORK_DIR / "suite.log").read_text()
    assert json.loads((out / "collect.json").read_text())["rollouts"] == []


def test_the_collect_suite_runs_the_declared_detectors_and_gives_the_ace_node_the_sims_urdf(tmp_path: Path) -> None:
    from sim_bridge.robot import URDF_PATH

    from fiper_ros.client.live_collect import LiveSettings, collect_config
    from fiper_ros.client.suite_process import installed_launch

    demo = installed_launch("demo.launch.yaml")
    settings = LiveSettings(task="stacking", model=MODELS / "stacking", batch=4, threads=1, max_policy_steps=2,
                            calibration=tmp_path, detectors=DETECTORS)
    config = collect_config(demo, settings)
    nodes = {spec.name: spec.parameters for spec in config.nodes}
    assert list(nodes) == ["bridge_node", "policy_node", "rnd_oe_node", "ace_node", "fusion_node"]
    assert nodes["ace_node"]["urdf_path"] == str(URDF_PATH) and nodes["ace_node"]["calibration_dir"] == str(tmp_path)
    assert "urdf_path" not in nodes["rnd_oe_node"]
    chosen = {"model": str(MODELS / "stacking"), "batch": 4, "torch_threads": 1, "task": "stacking",
              "max_policy_steps": 2}
    assert (nodes["policy_node"] | nodes["bridge_node"]).items() >= chosen.items()
    assert all(spec.required for spec in config.nodes)
    # the fusion node fuses the detectors the calibration declares; observation-only: RND-OE alone, no ACE node
    assert nodes["fusion_node"]["calibration_dir"] == nodes["rnd_oe_node"]["calibration_dir"] == str(tmp_path)
    alone = collect_config(demo, replace(settings, detectors=OBSERVATION_ONLY))
    assert [spec.name for spec in alone.nodes] == ["bridge_node", "policy_node", "rnd_oe_node", "fusion_node"]
    unscored = collect_config(demo, replace(settings, calibration=None, detectors=()))
    assert [spec.name for spec in unscored.nodes] == ["bridge_node", "policy_node"]


def test_a_live_stacking_rollout_is_the_in_process_episode_and_scored_as_the_bag_says(tmp_path: Path) -> None:
    """T_h = 2: the policy node acts on consecutive control steps (the bridge publishes the one before each
    tick), so the live rollout is the in-process episode bit for bit. The ACE node integrates each batch
    from the joint state stamped with it (not the later states of the control steps that run meanwhile),
    so the live alarms equal the offline oracle's on the bag."""
    from sim_bridge.robot import URDF_PATH

    from fiper_ros.core.kinematics import PinocchioFK

    out = tmp_path / "stacking"
    calibration_dir = MODELS / "stacking" / "calibration"
    steps = 6
    assert main(["collect", "--task", "stacking", "--episodes", "1", "--seed", "1003", "--batch", "8",
                 "--max-policy-steps", str(steps), "--ros", "--calibration", str(calibration_dir),
                 "--out", str(out)]) == 0
    (bag,) = find_bags([out])
    with BagReader(bag) as reader:
        (event, *_) = [reader.decode(m) for m in reader.messages([EVENTS_TOPIC])]
        recorded = alarm_steps(reader, event.rollout_id)
        states = {stamp_ns(m.header.stamp): m
                  for m in (reader.decode(r) for r in reader.messages([JOINT_STATES_TOPIC]))}
        batch_stamps = [stamp_ns(reader.decode(m).header.stamp) for m in reader.messages([ACTIONS_TOPIC])]
    assert len(states) > steps and set(range(steps - 1)) <= set(recorded)  # the control steps' states as well
    (rollout,) = read_rollouts(bag)
    episode = run_episode(Policy.load(MODELS / "stacking"), "id", 1003, batch=8, max_policy_steps=steps)
    assert episode.rollout is not None
    np.testing.assert_array_equal(rollout.embeddings, episode.rollout.embeddings)
    np.testing.assert_array_equal(rollout.actions, episode.rollout.actions)
    np.testing.assert_array_equal(np.asarray(rollout.metadata["joint_positions"], np.float32),  # the bag: float64
                                  episode.rollout.metadata["joint_positions"])
    np.testing.assert_array_equal(rollout.metadata["joint_positions"],
                                  [np.asarray(states[stamp].position[:7]) for stamp in batch_stamps])
    (offline,) = predict_bag(bag, load_calibration(calibration_dir), PinocchioFK(URDF_PATH, "panda_hand"))
    assert recorded == {step: offline.steps[step] for step in recorded}
