"""``fiper convert generic`` of users' logs as they come: per-step signals (``--signals-key``, ``--signal-names``),
several tasks in one conversion (a folder of bags per task), and no split (a seeded ``--calibration-fraction`` of
each task's successes is calibration, printed and written to ``split.json``). Small logs are written here; the bags
are read back by hand and as rollouts."""
from __future__ import annotations

import hashlib
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from helpers.converted import read_converted

from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader, find_bags
from fiper_ros.cli import main
from fiper_ros.commands.convert import SPLIT_FILE, convert
from fiper_ros.converters.options import ConvertOptions, Keys
from fiper_ros.core.data_split import split_by_task
from fiper_ros.interface.conversions import stamp_ns
from fiper_ros.interface.topics import EMBEDDING_TOPIC, EVENTS_TOPIC, STEP_SIGNALS_TOPIC

NAMES = ("chunk_mse", "eef_z", "action_jerk")


def _signals_options(**options: Any) -> ConvertOptions:
    return ConvertOptions(exec_steps=1, keys=Keys(signals="action_features"), signal_names=NAMES, **options)


def _table(path: Path, rollouts: list[tuple[str, str, bool, int]], *, seed: int = 0, embedding_dim: int = 4,
           split: bool = False, **extra: Any) -> dict[str, np.ndarray]:
    """An .npz table of observation-only rollouts ``(id, task, success, steps)`` with 3 signals per step, rows in
    order of (rollout, step); returns the per-step features by rollout id."""
    rng = np.random.default_rng(seed)
    ids, tasks, ok, steps, features = [], [], [], [], {}
    for name, task, success, length in rollouts:
        ids += [name] * length
        tasks += [task] * length
        ok += [success] * length
        steps += list(range(length))
        features[name] = rng.normal(size=(length, 3)).astype(np.float32)
    arrays = {"rollout_id": np.array(ids), "task": np.array(tasks), "success": np.array(ok), "step": np.array(steps),
              "embeddings": rng.normal(size=(len(ids), embedding_dim)).astype(np.float32),
              "action_features": np.concatenate(list(features.values())), **extra}
    if split:
        arrays["split"] = np.array(["calibration" if s else "test" for s in ok])
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savez(path, **arrays)
    return features


def _messages(bag: Path, topics: list[str]) -> list[tuple[str, Any]]:
    with BagReader(bag) as reader:
        return [(m.topic, reader.decode(m)) for m in reader.messages(topics)]


def test_signals_by_hand(tmp_path: Path) -> None:
    """Each step's signals: one StepSignals message after its embedding, same rollout, step and stamp; read back
    as float64 series equal to the logged float32 values."""
    src = tmp_path / "logs.npz"
    features = _table(src, [("a", "pick", True, 2), ("b", "pick", False, 1)], split=True)
    convert("generic", src, tmp_path / "out", _signals_options())
    messages = _messages(tmp_path / "out" / "calibration_rollouts", [EMBEDDING_TOPIC, STEP_SIGNALS_TOPIC, EVENTS_TOPIC])
    assert [t for t, _ in messages] == [EVENTS_TOPIC, EMBEDDING_TOPIC, STEP_SIGNALS_TOPIC, EMBEDDING_TOPIC,
                                        STEP_SIGNALS_TOPIC, EVENTS_TOPIC]
    _, e0, s0, e1, s1, _ = (m for _, m in messages)
    assert [(s.rollout_id, s.step) for s in (s0, s1)] == [(e.rollout_id, e.step) for e in (e0, e1)] == [(1, 0), (1, 1)]
    assert [stamp_ns(s.header.stamp) for s in (s0, s1)] == [stamp_ns(e.header.stamp) for e in (e0, e1)]
    assert list(s1.names) == list(NAMES)
    assert list(s1.values) == [float(v) for v in features["a"][1]]
    converted = read_converted(tmp_path / "out")
    rollout = converted["logs.npz#b"][1]
    assert list(rollout.signals) == list(NAMES)
    assert all(rollout.signals[n].dtype == np.float64 for n in NAMES)
    assert rollout.signals["eef_z"].tolist() == [float(features["b"][0, 1])]


def test_a_one_dimensional_signal_is_named_after_its_key(tmp_path: Path) -> None:
    src = tmp_path / "calibration" / "run.npz"
    src.parent.mkdir()
    np.savez(src, embeddings=np.ones((3, 2), np.float32), success=np.array(True), chunk_mse=np.array([0.5, 1, 2]),
             step=np.array([2, 0, 1]))
    convert("generic", tmp_path, tmp_path / "out", ConvertOptions(exec_steps=1, keys=Keys(signals="chunk_mse")))
    (_, rollout), = read_converted(tmp_path / "out").values()
    assert {k: v.tolist() for k, v in rollout.signals.items()} == {"chunk_mse": [1.0, 2.0, 0.5]}  # step order
    convert("generic", tmp_path, tmp_path / "named", ConvertOptions(exec_steps=1, keys=Keys(signals="chunk_mse"),
                                                                     signal_names=("disagreement",)))
    (_, rollout), = read_converted(tmp_path / "named").values()
    assert list(rollout.signals) == ["disagreement"]
    np.savez(src, embeddings=np.ones((3, 2), np.float32), success=np.array(True), **{"Chunk-MSE": np.ones(3)})
    with pytest.raises(BagError, match=f"^{re.escape(str(src))}: rollout 'run': 'Chunk-MSE' \\(--signals-key\\) holds "
                                       "one signal per step, named after its key, but 'Chunk-MSE' is no signal name "
                                       r"\(\^\[a-z\]\[a-z0-9_\]\*\$\): give --signal-names NAME$"):
        convert("generic", tmp_path, tmp_path / "bad", ConvertOptions(exec_steps=1, keys=Keys(signals="Chunk-MSE")))


BAD_SIGNALS = {  # name: (arrays of run.npz, options, message after "FILE: rollout 'run': ")
    "no signal names": ({}, {"signal_names": ()},
                        r"'action_features' \(--signals-key\) has K = 3 signals per step, no --signal-names given: "
                        "name each column$"),
    "too few names": ({}, {"signal_names": ("a", "b")},
                      r"'action_features' \(--signals-key\) has K = 3 signals per step, --signal-names names 2: "),
    "key missing": ({"action_features": None}, {}, r"no signals 'action_features' \(--signals-key\)$"),
    "NaN": ({"action_features": np.array([[0, 1, 2], [3, 4, np.nan]])}, {},
            r"'action_features' \(--signals-key\) holds NaN/inf \(first at step 1, index \[1, 2\]\)$"),
    "steps disagree": ({"action_features": np.ones((3, 3))}, {},
                       r"'embeddings' \(--embedding-key\) has T = 2 steps, 'action_features' \(--signals-key\) T = 3$"),
    "three axes": ({"action_features": np.ones((2, 3, 1))}, {},
                   r"'action_features' \(--signals-key\) has shape \(2, 3, 1\), expected \[T, K\] \(or \[T\]: one "
                   r"signal\)$"),
}


@pytest.mark.parametrize("case", sorted(BAD_SIGNALS))
def test_each_bad_signal_input_is_named(tmp_path: Path, case: str) -> None:
    arrays, options, message = BAD_SIGNALS[case]
    path = tmp_path / "calibration" / "run.npz"
    path.parent.mkdir()
    fields = {"embeddings": np.ones((2, 3), np.float32), "success": np.array(True),
              "action_features": np.ones((2, 3), np.float32), **arrays}
    np.savez(path, **{k: v for k, v in fields.items() if v is not None})
    settings = {"signal_names": NAMES, **options}
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: rollout 'run': {message}"):
        convert("generic", tmp_path, tmp_path / "out",
                ConvertOptions(exec_steps=1, keys=Keys(signals="action_features"), **settings))
    assert not (tmp_path / "out").exists()


def test_bad_signal_options_are_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(BagError, match="--signal-names names the columns of --signals-key: give --signals-key too"):
        ConvertOptions(signal_names=("a",))
    with pytest.raises(BagError, match=r"--signal-names: signal name 'Gripper' must match \^\[a-z\]"):
        ConvertOptions(keys=Keys(signals="f"), signal_names=("a", "Gripper"))
    with pytest.raises(BagError, match=r"--signal-names repeats a name \(a, b, a\)"):
        ConvertOptions(keys=Keys(signals="f"), signal_names=("a", "b", "a"))
    with pytest.raises(BagError, match="distinct"):
        Keys(signals="embeddings")
    argv = ["convert", "generic", str(tmp_path), "-o", str(tmp_path / "out"), "--signals-key", "f",
            "--signal-names", "a,Gripper"]
    assert main(argv) == 2
    assert capsys.readouterr().err == ("fiper convert: --signal-names: signal name 'Gripper' must match "
                                       "^[a-z][a-z0-9_]*$ (lower-case letters, digits and _, a letter first)\n")


def test_several_tasks_give_a_folder_of_bags_per_task(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Two tasks of one layout in two files: OUT/<task>/{calibration,test}_rollouts, ids and the time line running on
    over all bags, task by task in name order, each bag of one task."""
    _table(tmp_path / "src" / "b.npz", [("p1", "pick", True, 2), ("p2", "pick", False, 3)], split=True)
    _table(tmp_path / "src" / "a.npz", [("o1", "open", False, 1), ("o2", "open", True, 2), ("o3", "open", True, 1)],
           seed=1, split=True)
    out = tmp_path / "out"
    argv = ["convert", "generic", str(tmp_path / "src"), "-o", str(out), "--exec-steps", "1", "--signals-key",
            "action_features", "--signal-names", ",".join(NAMES)]
    assert main(argv) == 0
    assert capsys.readouterr().out.splitlines() == [
        f"{out}/open/calibration_rollouts: 2 rollouts", f"{out}/open/test_rollouts: 1 rollouts",
        f"{out}/pick/calibration_rollouts: 1 rollouts", f"{out}/pick/test_rollouts: 1 rollouts"]
    bags = find_bags([out])
    assert [str(b.relative_to(out)) for b in bags] == ["open/calibration_rollouts", "open/test_rollouts",
                                                       "pick/calibration_rollouts", "pick/test_rollouts"]
    starts, ends = [], []
    for bag in bags:
        with BagReader(bag) as reader:
            assert reader.info.task == bag.parent.name and reader.info.split_rule == ""
            starts.append(reader.start_ns)
            ends.append(max(m.log_time_ns for m in reader.messages()))
            events = [reader.decode(m) for m in reader.messages([EVENTS_TOPIC])]
        assert {e.task for e in events if e.event == 0} == {bag.parent.name}
    assert all(end < start for end, start in zip(ends, starts[1:]))  # one time line over all bags
    converted = read_converted(out)
    ids = {source: int(r.rollout_id) for source, (_, r) in converted.items()}
    assert ids == {"a.npz#o2": 1, "a.npz#o3": 2, "a.npz#o1": 3, "b.npz#p1": 4, "b.npz#p2": 5}


def test_several_tasks_of_different_layouts_are_refused(tmp_path: Path) -> None:
    _table(tmp_path / "src" / "a.npz", [("o1", "open", True, 2)], split=True)
    other = tmp_path / "src" / "b.npz"
    _table(other, [("p1", "pick", True, 2)], embedding_dim=5, split=True)
    first = re.escape(f"rollout 'o1' of {tmp_path / 'src' / 'a.npz'}")
    with pytest.raises(BagError, match=f"^{re.escape(str(other))}: rollout 'p1': 'embeddings' \\(--embedding-key\\) "
                                       f"has E = 5, {first} E = 4: one conversion holds one layout$"):
        convert("generic", tmp_path / "src", tmp_path / "out", _signals_options())
    other.unlink()
    _table(tmp_path / "src" / "c.npz", [("q1", "pusht", True, 2)], split=True)
    _table(tmp_path / "src" / "a.npz", [("o1", "sorting", True, 2)], split=True)
    with pytest.raises(BagError, match=r"^.*c\.npz: rollout 'q1': h = 8 .*, rollout 'o1' .* h = 4: one conversion"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions())  # known tasks' h: 4 and 8


def _outcomes(task: str, successes: int, failures: int) -> list[tuple[str, str, bool, int]]:
    return ([(f"{task}-{i:02d}", task, True, 1 + i % 3) for i in range(successes)]
            + [(f"{task}-f{i}", task, False, 2) for i in range(failures)])


def test_without_a_split_a_seeded_fraction_of_each_tasks_successes_is_calibration(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "logs.npz"
    _table(src, _outcomes("open", 10, 3) + _outcomes("pick", 16, 0))
    out = tmp_path / "out"
    argv = ["convert", "generic", str(src), "-o", str(out), "--exec-steps", "1", "--calibration-fraction", "0.8",
            "--split-seed", "5"]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[4:] == [
        f"no split given: drawn per task with --calibration-fraction 0.8 --split-seed 5 ({out / SPLIT_FILE}):",
        "  open: 13 rollouts (10 successes, 3 failures): calibration 8 successes, test 2 successes and 3 failures",
        "  pick: 16 rollouts (16 successes, 0 failures): calibration 13 successes, test 3 successes and 0 failures"]
    converted = read_converted(out)
    calibration = {source for source, (split, _) in converted.items() if split == "calibration"}
    written = json.loads((out / SPLIT_FILE).read_text())
    content_hash = written.pop("content_hash")
    assert content_hash == hashlib.sha256(json.dumps(written, sort_keys=True).encode()).hexdigest()
    assert (written["format_version"], written["calibration_fraction"], written["split_seed"]) == (1, 0.8, 5)
    assert set(written["tasks"]["open"]["calibration"]) | set(written["tasks"]["pick"]["calibration"]) == calibration
    assert written["tasks"]["open"]["test"] == [f"logs.npz#{name}" for name in
                                                 sorted(set(f"open-{i:02d}" for i in range(10))
                                                        - {s.split("#")[1] for s in calibration})] + [
        "logs.npz#open-f0", "logs.npz#open-f1", "logs.npz#open-f2"]
    # the rule of core.data_split over the rollouts in their order in the logs
    rollouts = [r for _, (_, r) in sorted(converted.items(), key=lambda item: item[0])]
    drawn = split_by_task(sorted(rollouts, key=lambda r: r.task), lambda r: r, 0.8, 5)
    assert {f"logs.npz#{name}" for name in
            [f"open-{i:02d}" for i in range(10)] + [f"pick-{i:02d}" for i in range(16)]} >= calibration
    assert len(calibration) == len(drawn["open"].calibration) + len(drawn["pick"].calibration) == 21
    for bag in find_bags([out]):
        with BagReader(bag) as reader:
            assert reader.info.split_rule == ("drawn: per task, calibration fraction 0.8 of its successes (seed 5), "
                                              "every other rollout test")
    # the same command again: the same split; another seed: another
    assert main([*argv[:4], str(tmp_path / "again"), *argv[5:]]) == 0
    assert json.loads((tmp_path / "again" / SPLIT_FILE).read_text())["tasks"] == written["tasks"]
    assert main([*argv[:4], str(tmp_path / "other"), *argv[5:-1], "6"]) == 0
    assert json.loads((tmp_path / "other" / SPLIT_FILE).read_text())["tasks"] != written["tasks"]


def test_a_fraction_that_leaves_a_task_too_few_calibration_successes_is_refused(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "logs.npz"
    _table(src, _outcomes("open", 10, 3) + _outcomes("pick", 40, 0))
    argv = ["convert", "generic", str(src), "-o", str(tmp_path / "out"), "--exec-steps", "1"]
    assert main(argv) == 2
    assert capsys.readouterr().err == (
        "fiper convert: task 'open': calibration fraction 0.5 draws 5 of its 10 successes; the default split-conformal "
        "calibration needs at least 8 (4 conformal, 4 to fit the score models): a fraction of 0.75 or more would do\n")
    assert not (tmp_path / "out").exists()
    assert main([*argv, "--calibration-fraction", "1.5"]) == 2
    assert capsys.readouterr().err == ("fiper convert: --calibration-fraction: calibration fraction must be in (0, 1), "
                                       "got 1.5\n")
    assert main([*argv, "--split-seed", "-1"]) == 2
    assert capsys.readouterr().err == "fiper convert: --split-seed: the seed must be >= 0, got -1\n"


def test_rollouts_with_and_without_a_split_are_refused(tmp_path: Path) -> None:
    _table(tmp_path / "src" / "test" / "a.npz", _outcomes("open", 10, 0))
    loose = tmp_path / "src" / "b.npz"
    _table(loose, _outcomes("open", 10, 0))
    with pytest.raises(BagError, match=f"^{re.escape(str(loose))}: rollout 'open-00': no split, while other rollouts "
                                       r"have one: give 'split' \(--split-key\) or put the file under calibration/ or "
                                       r"test/ \(without a split for any rollout, the conversion draws one: "
                                       r"--calibration-fraction\)$"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1))
