"""``fiper collect``: one bag per closed-loop rollout, resume, ``--successes``, the index, joint states.

Short episodes keep it fast: the shipped Sorting model with B = 4 and 2 policy steps (every episode is
then a timeout failure; ``--successes`` is tested with outcomes assigned per seed), and a tiny untrained
Stacking model for the joint-velocity path.
"""
from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tracemalloc
from collections import Counter
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from helpers.policy_fixtures import tiny_policy
from rclpy.serialization import deserialize_message
from sensor_msgs.msg import JointState
from sim_bridge import collect_runner
from sim_bridge.closed_loop import EpisodeResult, run_episode
from sim_bridge.collect_runner import collected_rollout_id
from sim_bridge.robot import URDF_PATH

from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.bagio.rollout_bags import _joint_state_cdr, read_rollouts
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.cli import main
from fiper_ros.commands import collect
from fiper_ros.commands.collect import bag_name
from fiper_ros.core.calibration import load_calibration
from fiper_ros.core.kinematics import PinocchioFK
from fiper_ros.evaluation.data import load_dataset
from fiper_ros.evaluation.offline import predict_bag
from fiper_ros.interface.topics import ACTIONS_TOPIC, ARM_JOINT_NAMES, EMBEDDING_TOPIC, EVENTS_TOPIC, JOINT_STATES_TOPIC
from fiper_ros.policy.policy import Policy

MODELS = Path(__file__).resolve().parents[2] / "models"
SMALL = ["--batch", "4", "--max-policy-steps", "2"]
ARGS = ["collect", "--task", "sorting", "--scenarios", "id", "camera_moved", "--episodes", "2", "--seed", "1000",
        *SMALL]


def _bag_bytes(folder: Path) -> dict[str, bytes]:
    """Relative path -> content of every file of every bag in ``folder``."""
    return {str(f.relative_to(folder)): f.read_bytes() for bag in find_bags([folder]) for f in bag.iterdir()}


@pytest.fixture(scope="module")
def collected(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two short episodes each of Sorting id and camera_moved (seeds 1000, 1001), test split."""
    out = tmp_path_factory.mktemp("collect") / "sorting"
    assert main([*ARGS, "--out", str(out)]) == 0
    return out


def test_collect_writes_one_readable_bag_per_rollout(collected: Path) -> None:
    assert sorted(p.name for p in collected.iterdir()) == ["camera_moved", "collect.json", "id"]  # no lock left
    bags = find_bags([collected])
    assert [b.relative_to(collected).as_posix() for b in bags] == [
        f"{scenario}/{bag_name('sorting', scenario, seed)}" for scenario in ("camera_moved", "id") for seed in (1000, 1001)]
    for bag in bags:
        scenario, seed = bag.parent.name, int(bag.name.rsplit("_", 1)[1])
        with BagReader(bag) as reader:
            counts = Counter(m.topic for m in reader.messages())
            events = [reader.decode(m) for m in reader.messages([EVENTS_TOPIC])]
            stamps = [m.log_time_ns for m in reader.messages([ACTIONS_TOPIC])]
            info = reader.info
        assert counts == {EVENTS_TOPIC: 2, EMBEDDING_TOPIC: 2,
                          ACTIONS_TOPIC: 2}  # no /joint_states for an ee_position task
        assert [(e.event, e.outcome, e.task, e.scenario, e.max_steps) for e in events] == [
            (0, 0, "sorting", scenario, 2), (1, 2, "sorting", scenario, 2)]  # START, END with FAILURE
        assert {e.rollout_id for e in events} == {collected_rollout_id(scenario, seed)}
        assert stamps[1] - stamps[0] == 4 * 100_000_000  # h = 4 control steps at the sim's 10 Hz
        assert (info.task, info.split, info.synthetic, info.seed, info.policy) == (
            "sorting", "test", False, str(seed), "models/sorting")
        assert (info.batch_size, info.horizon, info.action_dim, info.embedding_dim) == (4, 8, 2, 128)
        assert info.policy_data_hash == yaml.safe_load((MODELS / "sorting" / "policy.yaml").read_text())["info"][
            "data_hash"]
        (rollout,) = read_rollouts(bag)
        assert (rollout.scenario, rollout.success, rollout.length, rollout.actions.shape) == (scenario, False, 2,
                                                                                              (2, 4, 8, 2))
    # the bag holds exactly the in-process rollout of that seed
    episode = run_episode(Policy.load(MODELS / "sorting"), "id", 1001, batch=4, max_policy_steps=2)
    (rollout,) = read_rollouts(collected / "id" / bag_name("sorting", "id", 1001))
    assert episode.rollout is not None
    np.testing.assert_array_equal(rollout.embeddings, episode.rollout.embeddings)
    np.testing.assert_array_equal(rollout.actions, episode.rollout.actions)
    index = json.loads((collected / "collect.json").read_text())
    assert (index["task"], index["split"], index["batch"], index["max_policy_steps"]) == ("sorting", "test", 4, 2)
    assert [(r["scenario"], r["seed"], r["success"], r["policy_steps"], r["bag"]) for r in index["rollouts"]] == [
        (b.parent.name, int(b.name[-6:]), False, 2, b.relative_to(collected).as_posix()) for b in bags]


def test_resume_skips_finished_bags_and_completes_a_killed_run_identically(
        collected: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sorting"
    shutil.copytree(collected, out)
    # a run killed while writing seed 1001's id bag: its index entry was written, the bag only half
    victim = out / "id" / bag_name("sorting", "id", 1001)
    shutil.copytree(victim, victim.parent / f".{victim.name}.partial-999999")
    shutil.rmtree(victim)
    (victim.parent / f".{victim.name}.partial-999999" / "metadata.yaml").write_text("truncated")
    assert main([*ARGS, "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("bag exists, skipped") == 3 and "seed 1001: failure, 2 policy steps" in err
    assert _bag_bytes(out) == _bag_bytes(collected)  # the same bags, byte for byte
    assert sorted(p.name for p in victim.parent.iterdir()) == [f"sorting_id_{s:06d}" for s in (1000, 1001)]

    def entries(folder: Path) -> list[dict]:
        return [{k: v for k, v in r.items() if k != "seconds"}
                for r in json.loads((folder / "collect.json").read_text())["rollouts"]]

    assert entries(out) == entries(collected)


def _outcome_by_seed(monkeypatch: pytest.MonkeyPatch) -> None:
    """Episodes with an even seed succeed (short episodes never do on their own)."""
    def episode(*args: object, **kwargs: object) -> EpisodeResult:
        result = run_episode(*args, **kwargs)  # type: ignore[arg-type]
        success = result.seed % 2 == 0
        assert result.rollout is not None
        return replace(result, success=success, rollout=replace(result.rollout, success=success))

    monkeypatch.setattr(collect_runner, "run_episode", episode)


def test_successes_stop_at_m_or_at_the_cap_and_the_folders_calibrate_and_evaluate(
        collected: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _outcome_by_seed(monkeypatch)
    out = tmp_path / "calibration"
    args = ["collect", "--task", "sorting", "--seed", "1000", "--split", "calibration", "--out", str(out), *SMALL]
    assert main([*args, "--successes", "2"]) == 0  # seeds 1000 (success), 1001, 1002 (success)
    assert [b.name for b in find_bags([out])] == [bag_name("sorting", "id", s) for s in (1000, 1001, 1002)]
    assert "successes 2/2 wanted" in capsys.readouterr().err
    assert main([*args, "--successes", "3", "--max-episodes", "4"]) == 1  # seed 1003 fails: cap reached
    captured = capsys.readouterr()
    assert captured.err.count("bag exists, skipped") == 3
    assert "fiper collect: id: only 2 of 3 successes after 4 episodes: --max-episodes 4 reached" in captured.err
    assert "id: 4 rollouts (seeds 1000-1003), 2 successes (0.50)" in captured.out
    assert len(json.loads((out / "collect.json").read_text())["runs"]) == 2

    dataset = load_dataset("sorting", [out, collected])
    assert [r.success for r in dataset.calibration] == [True, False, True, False]
    assert len(dataset.test) == 4 and set(dataset.categories) == {"Fail-ID", "Fail-OOD"}
    calibration = tmp_path / "fiper_calibration"
    assert main(["calibrate", str(out), "-o", str(calibration), "--min-rollouts", "2", "--window-obs", "1",
                 "--window-act", "1", "--threshold", "cp_constant", "--delta", "0.4", "--max-epochs", "2",
                 "--same-data"]) == 0  # two successes: too few to split, the mechanics are the point here
    assert "calibrating on 2 successful rollouts (4 steps) of 4" in capsys.readouterr().out


def _tiny_model(directory: Path, task: str) -> Path:
    """An untrained tiny ``task`` model folder."""
    tiny_policy(task).save(directory, {"data_hash": f"tiny-{task}"})
    return directory


def test_a_folder_of_other_settings_is_refused(collected: Path, tmp_path: Path,
                                               capsys: pytest.CaptureFixture[str]) -> None:
    def refusal(*extra: str, out: Path = collected) -> str:
        assert main([*ARGS[:-len(SMALL)], "--out", str(out), *extra]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and err.startswith("fiper collect: ")
        return err

    err = refusal("--batch", "3", "--max-policy-steps", "2")
    assert f"{collected / 'collect.json'}: the folder was collected with other settings (batch 4 != 3" in err
    assert "policy_hash" in refusal("--model", str(_tiny_model(tmp_path / "tiny_sorting", "sorting")), *SMALL)
    stacking = ["collect", "--task", "stacking", "--episodes", "1", "--out", str(collected), "--model"]
    assert main([*stacking, str(_tiny_model(tmp_path / "tiny_stacking", "stacking"))]) == 2
    assert "(task 'sorting' != 'stacking'; policy_hash" in capsys.readouterr().err
    assert main([*stacking, str(tmp_path / "tiny_sorting")]) == 2
    assert "tiny_sorting: a sorting policy, not stacking" in capsys.readouterr().err
    foreign = tmp_path / "foreign"
    shutil.copytree(collected / "id", foreign / "id")
    assert "holds bags but no collect.json" in refusal(*SMALL, out=foreign)
    assert "unknown scenario 'moon'" in refusal(*SMALL, "--scenarios", "moon", out=tmp_path / "z")
    assert not (tmp_path / "z").exists()


def test_a_scenario_whose_knobs_changed_is_refused(collected: Path, tmp_path: Path,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    index = json.loads((collected / "collect.json").read_text())
    assert index["scenarios"] == {"id": {}, "camera_moved": {"camera_shift": [0.25, 0.3]}}
    folder = tmp_path / "sorting"
    shutil.copytree(collected, folder)
    index["scenarios"]["camera_moved"]["camera_shift"] = [0.2, 0.25]  # as if collected before a retune
    (folder / "collect.json").write_text(json.dumps(index))
    assert main([*ARGS, "--out", str(folder)]) == 2
    assert ("fiper collect: scenario 'camera_moved' has changed since its rollouts in this folder were collected "
            "(knobs {'camera_shift': [0.2, 0.25]} then, {'camera_shift': [0.25, 0.3]} now)") in capsys.readouterr().err
    del index["scenarios"]  # an index from before the knobs were recorded: resumed, knobs recorded from now on
    (folder / "collect.json").write_text(json.dumps(index))
    assert main([*ARGS, "--out", str(folder)]) == 0
    recorded = json.loads((folder / "collect.json").read_text())["scenarios"]
    assert recorded["camera_moved"] == {"camera_shift": [0.25, 0.3]}


def _stacking_bag(tmp_path: Path, steps: int) -> tuple[Path, Path]:
    """A tiny Stacking (joint-velocity) policy and the bag of its seed-5 episode of ``steps`` policy steps."""
    model = _tiny_model(tmp_path / "tiny_stacking", "stacking")
    out = tmp_path / "stacking"
    assert main(["collect", "--task", "stacking", "--episodes", "1", "--seed", "5", "--model", str(model),
                 "--out", str(out), "--max-policy-steps", str(steps)]) == 0
    (bag,) = find_bags([out])
    return model, bag


def test_joint_velocity_rollouts_keep_their_joint_states_through_the_bag(tmp_path: Path) -> None:
    model, bag = _stacking_bag(tmp_path, 2)
    with BagReader(bag) as reader:
        joint_states = [(m.log_time_ns, reader.decode(m)) for m in reader.messages([JOINT_STATES_TOPIC])]
        raw = next(reader.messages([JOINT_STATES_TOPIC])).raw
        batches = [m.log_time_ns for m in reader.messages([ACTIONS_TOPIC])]
        order = [m.topic for m in reader.messages()]
    assert [t for t, _ in joint_states] == batches  # one per policy step, at the step's stamp
    assert order[1:4] == [JOINT_STATES_TOPIC, EMBEDDING_TOPIC, ACTIONS_TOPIC]  # before the step's batch
    assert all(list(msg.name) == list(ARM_JOINT_NAMES) for _, msg in joint_states)
    assert list(deserialize_message(raw, JointState).name) == list(ARM_JOINT_NAMES)  # what a replayed ace_node gets
    (rollout,) = read_rollouts(bag)
    episode = run_episode(Policy.load(model), "id", 5, max_policy_steps=2)
    assert episode.rollout is not None and rollout.action_space == "joint_velocity"
    np.testing.assert_array_equal(rollout.metadata["joint_positions"], episode.rollout.metadata["joint_positions"])
    assert rollout.metadata["joint_positions"].shape == (2, 7)


def test_a_batch_logged_before_the_joint_state_of_its_stamp_gets_that_state(tmp_path: Path) -> None:
    # Seen in the live Stacking test under load: the recorder took step 1's batch before the joint states
    # stamped up to it, and the bag reader, taking the latest state logged before the batch, gave step 1 the
    # state of an earlier control step. The rule is the ACE node's over the stamps of all the bag's states.
    _, bag = _stacking_bag(tmp_path, 3)
    late = tmp_path / "late_states"
    with BagReader(bag) as reader, BagWriter(late) as writer:
        writer.info = reader.info
        for message in reader.messages():  # each state 1 ns after its step's batch in the log
            log_time = message.log_time_ns + (1 if message.topic == JOINT_STATES_TOPIC else 0)
            writer.write(message.topic, log_time, message.raw, message.msgtype)
    with BagReader(late) as reader:
        order = [m.topic for m in reader.messages([JOINT_STATES_TOPIC, ACTIONS_TOPIC])]
    assert order[:2] == [ACTIONS_TOPIC, JOINT_STATES_TOPIC]
    (original,) = read_rollouts(bag)
    (rollout,) = read_rollouts(late)
    np.testing.assert_array_equal(rollout.metadata["joint_positions"], original.metadata["joint_positions"])


def test_reading_a_bag_of_many_joint_states_keeps_no_more_of_them_than_its_batches(tmp_path: Path) -> None:
    # #18: the reader kept every /joint_states message of a bag (any of them can be a batch's answer when the
    # log order is not the stamps'); it now keeps at most one per batch. rosbags' own reading of the bag costs
    # about 670 bytes per message (its index): what read_rollouts adds on top of that must not grow with them.
    _, bag = _stacking_bag(tmp_path, 3)
    crowded, extra = tmp_path / "crowded", 30_000
    with BagReader(bag) as reader, BagWriter(crowded) as writer:
        writer.info = reader.info
        first = next(reader.messages([JOINT_STATES_TOPIC]))
        for index in range(extra):  # stamped before the first step's state: never a batch's answer
            writer.write(JOINT_STATES_TOPIC, first.log_time_ns, _joint_state_cdr(index + 1, np.full(7, float(index))),
                         first.msgtype)
        for message in reader.messages():
            writer.write(message.topic, message.log_time_ns, message.raw, message.msgtype)

    def peak(read: Callable[[], object]) -> int:
        tracemalloc.start()
        try:
            read()
            return tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()

    def iterate() -> None:
        with BagReader(crowded) as reader:
            for _ in reader.messages():
                pass

    added = peak(lambda: read_rollouts(crowded)) - peak(iterate)
    assert added < 700_000, added  # 0.38 MB; the old reader, keeping all 30,000: 1.03 MB
    (original,), (rollout,) = read_rollouts(bag), read_rollouts(crowded)
    np.testing.assert_array_equal(rollout.metadata["joint_positions"], original.metadata["joint_positions"])


def test_jobs_write_the_folder_one_process_writes(collected: Path, tmp_path: Path,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "sorting"
    assert main([*ARGS, "--jobs", "2", "--out", str(out)]) == 0
    assert _bag_bytes(out) == _bag_bytes(collected)  # the same bags, byte for byte
    capped = tmp_path / "capped"  # every short episode fails: --successes runs to its cap, in seed order
    assert main(["collect", "--task", "sorting", "--seed", "1000", "--successes", "1", "--max-episodes", "3",
                 "--jobs", "2", "--out", str(capped), *SMALL]) == 1
    assert [b.name for b in find_bags([capped])] == [bag_name("sorting", "id", s) for s in (1000, 1001, 1002)]
    assert main([*ARGS, "--jobs", "2", "--ros", "--out", str(tmp_path / "ros")]) == 2
    assert "--jobs runs episodes in worker processes" in capsys.readouterr().err


def test_workers_run_ahead_and_drop_episodes_no_longer_wanted() -> None:
    policy = Policy.load(MODELS / "sorting")
    setup = collect.CollectSetup("sorting", "hash", "test", 4, 2, collect.IN_PROCESS)
    runner = collect_runner.InProcessRunner(policy, setup, jobs=2, model_dir=MODELS / "sorting")
    try:
        runner.ahead("id", iter([1000, 1001, 1002]))  # the first two start
        assert sorted(runner._started) == [("id", 1000), ("id", 1001)]
        runner.ahead("camera_moved", [1005])  # a success ended "id" early: both are dropped
        assert runner.discarded == 2 and list(runner._started) == [("camera_moved", 1005)]
        ran = runner.run("camera_moved", 1005, Path("unused"), {})
        expected = run_episode(policy, "camera_moved", 1005, batch=4, max_policy_steps=2)
        assert (ran.policy_steps, ran.control_steps) == (expected.policy_steps, expected.control_steps) == (2, 8)
        assert not runner._started
    finally:
        runner.close()


def _workers_of(pid: int) -> list[int]:
    """The pids of ``pid``'s spawned worker processes (multiprocessing's ``spawn_main``)."""
    workers = []
    for child in Path("/proc").glob("[0-9]*"):
        try:
            ppid = int((child / "stat").read_text().rsplit(")", 1)[1].split()[1])
            command = (child / "cmdline").read_bytes()
        except (OSError, IndexError, ValueError):
            continue
        if ppid == pid and b"spawn_main" in command:
            workers.append(int(child.name))
    return workers


def test_killing_a_collect_stops_its_workers(tmp_path: Path) -> None:
    # PushT episodes at B = 256 take tens of seconds: a worker left alone would keep running for that long
    collect_cmd = [sys.executable, "-m", "fiper_ros.cli", "collect", "--task", "pusht", "--episodes", "10",
                   "--jobs", "2", "--out", str(tmp_path / "out")]
    proc = subprocess.Popen(collect_cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while len(_workers_of(proc.pid)) < 2 and time.monotonic() < deadline:
            time.sleep(0.2)
        workers = _workers_of(proc.pid)
        assert len(workers) == 2 and proc.poll() is None
        first = tmp_path / "out" / "id" / bag_name("pusht", "id", 1000) / "metadata.yaml"
        while not first.is_file() and time.monotonic() < deadline:  # then both workers are in an episode
            time.sleep(0.2)
        assert first.is_file()
    finally:
        proc.kill()  # no clean-up at all
        proc.wait()
    deadline = time.monotonic() + 10
    while any(Path(f"/proc/{pid}").exists() for pid in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    alive = [pid for pid in workers if Path(f"/proc/{pid}").exists()]
    for pid in alive:
        os.kill(pid, signal.SIGKILL)
    assert not alive, "workers outlived their collect"



def test_joint_velocity_bags_calibrate_and_replay_through_the_panda_fk_and_are_refused_without_it(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    _outcome_by_seed(monkeypatch)
    model = _tiny_model(tmp_path / "tiny_stacking", "stacking")
    out = tmp_path / "stacking"
    assert main(["collect", "--task", "stacking", "--episodes", "4", "--seed", "1000", "--model", str(model),
                 "--split", "calibration", "--out", str(out), "--max-policy-steps", "3"]) == 0
    calibrate = ["calibrate", str(out), "--min-rollouts", "2", "--window-obs", "1", "--window-act", "1",
                 "--threshold", "cp_constant", "--delta", "0.4", "--max-epochs", "2", "--same-data"]
    capsys.readouterr()
    assert main([*calibrate, "-o", str(tmp_path / "refused")]) == 2
    assert "give the robot model with --urdf, --ee-frame and --control-dt" in capsys.readouterr().err
    assert not (tmp_path / "refused").exists()
    assert main([*calibrate, "-o", str(tmp_path / "refused"), "--urdf", str(URDF_PATH)]) == 2  # velocities: no dt
    assert "'joint_velocity' needs dt > 0" in capsys.readouterr().err

    calibration = tmp_path / "calibration"
    assert main([*calibrate, "-o", str(calibration), "--urdf", str(URDF_PATH), "--control-dt", "0.1"]) == 0
    cal = load_calibration(calibration)
    assert cal.layout.action_space == "joint_velocity" and cal.settings.control_dt == 0.1
    ranges = cal.scorer("ace").ranges  # R_d of hand positions: within twice the reach (0.855 m)
    assert ranges.shape == (3,) and np.all(ranges > 0) and np.all(ranges < 1.8)

    replay = ["replay", "--offline", "--calibration", str(calibration), str(out)]
    capsys.readouterr()
    assert main(replay) == 2
    assert "give the robot model with --urdf" in capsys.readouterr().err
    assert main([*replay, "--urdf", str(URDF_PATH), "--report", str(tmp_path / "report.json")]) == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert [len(r["steps"]) for r in report["rollouts"]] == [3, 3, 3, 3]
    expected = [r.to_dict() for r in predict_bag(find_bags([out])[0], cal, PinocchioFK(URDF_PATH, "panda_hand"))]
    assert report["rollouts"][0] == expected[0]

    test = tmp_path / "stacking_test"
    assert main(["collect", "--task", "stacking", "--episodes", "2", "--seed", "1004", "--model", str(model),
                 "--out", str(test), "--max-policy-steps", "3"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--data", f"stacking={out},{test}", "--tiny", "--no-cache", "--out", str(tmp_path / "eval")]) == 2
    assert "task 'stacking' has joint_velocity actions: ACE needs the robot's URDF" in capsys.readouterr().err
