"""``fiper convert generic``: users' rollout logs (.npz, .parquet, pickled lists of dicts) -> FIPER bags.

Small files written here in each layout of docs/bags.md; the bags are read back with the project's bag reader
(values by hand) and as rollouts (equal to the input arrays); every bad input is one line naming the file, the
rollout and the key."""
from __future__ import annotations

import pickle
import re
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow
import pyarrow.parquet
import pytest
from helpers.converted import read_converted

from fiper_msgs.msg import RolloutEvent
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader
from fiper_ros.cli import main
from fiper_ros.commands.convert import convert
from fiper_ros.converters.options import ConvertOptions, Keys
from fiper_ros.core.rollout import Rollout, RolloutError
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC


def _observation_only_supported() -> bool:
    """Whether core Rollouts may have no action batches (``actions=None``, the observation-only support of #19)."""
    try:
        Rollout("probe", "t", "id", np.zeros((1, 1)), None, 1, True)  # type: ignore[arg-type]
    except RolloutError:
        return False
    return True


needs_observation_only = pytest.mark.skipif(not _observation_only_supported(),
                                            reason="core Rollout without action batches (observation-only, #19)")


def _arrays(seed: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """Embeddings [T, 3] and action batches [T, 2, 4, 2] of a rollout."""
    rng = np.random.default_rng(seed)
    return rng.normal(size=(steps, 3)).astype(np.float32), rng.normal(size=(steps, 2, 4, 2)).astype(np.float32)


def _messages(bag: Path) -> list[tuple[str, Any]]:
    with BagReader(bag) as reader:
        return [(m.topic, reader.decode(m)) for m in reader.messages()]


def test_npz_by_hand(tmp_path: Path) -> None:
    """One .npz table of two rollouts (rows grouped by rollout_id, per-step labels): every message by hand."""
    src = tmp_path / "logs.npz"
    np.savez(src, rollout_id=np.array(["a", "a", "b"]), embeddings=np.array([[1, 2], [3, 4], [5, 6]], np.float32),
             actions=np.arange(3 * 1 * 2 * 1, dtype=np.float32).reshape(3, 1, 2, 1) / 2,
             success=np.array([True, True, False]), split=np.array(["calibration", "calibration", "test"]),
             task=np.array("pusht"), scenario=np.array(["id", "id", "lighting"]))
    counts = convert("generic", src, tmp_path / "out", ConvertOptions(exec_steps=1))
    assert counts.bags == {"calibration_rollouts": 1, "test_rollouts": 1}
    calibration = _messages(tmp_path / "out" / "calibration_rollouts")
    assert [t for t, _ in calibration] == [EVENTS_TOPIC, EMBEDDING_TOPIC, ACTIONS_TOPIC, EMBEDDING_TOPIC, ACTIONS_TOPIC,
                                           EVENTS_TOPIC]
    start, e0, a0, e1, a1, end = (m for _, m in calibration)
    assert (start.event, start.task, start.scenario, start.rollout_id) == (RolloutEvent.EVENT_START, "pusht", "id", 1)
    assert list(e0.data) == [1.0, 2.0] and list(e1.data) == [3.0, 4.0] and (e0.step, e1.step) == (0, 1)
    assert list(a0.data) == [0.0, 0.5] and list(a1.data) == [1.0, 1.5]
    assert (a0.batch_size, a0.horizon, a0.action_dim, a0.exec_steps, a0.action_space) == (1, 2, 1, 1, "ee_position")
    assert (end.event, end.outcome) == (RolloutEvent.EVENT_END, RolloutEvent.OUTCOME_SUCCESS)
    test = [m for _, m in _messages(tmp_path / "out" / "test_rollouts")]
    assert (test[0].scenario, test[0].rollout_id, list(test[1].data), list(test[2].data)) == ("lighting", 2, [5.0, 6.0],
                                                                                              [2.0, 2.5])
    assert test[-1].outcome == RolloutEvent.OUTCOME_FAILURE
    assert {k: s for k, (s, _) in read_converted(tmp_path / "out").items()} == {"logs.npz#a": "calibration",
                                                                          "logs.npz#b": "test"}


def test_npz_one_rollout_per_file_round_trip(tmp_path: Path) -> None:
    """One rollout per .npz (0-d labels), split from the directory: read back equal to the input arrays."""
    expected = {}
    for split, index, success in (("calibration", 0, True), ("calibration", 1, True), ("test", 2, False)):
        embeddings, actions = _arrays(index, 4 + index)
        (tmp_path / "src" / split).mkdir(parents=True, exist_ok=True)
        np.savez(tmp_path / "src" / split / f"run{index}.npz", embeddings=embeddings, actions=actions,
                 success=np.array(success))
        expected[f"{split}/run{index}.npz"] = (split, success, embeddings, actions)
    convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=2))
    converted = read_converted(tmp_path / "out")
    assert sorted(converted) == sorted(expected)
    for name, (split, success, embeddings, actions) in expected.items():
        bag_split, rollout = converted[name]
        assert (bag_split, rollout.success, rollout.task, rollout.scenario, rollout.exec_steps) == (
            split, success, "src", "id", 2)
        assert np.array_equal(rollout.embeddings, embeddings) and np.array_equal(rollout.actions, actions)


def test_parquet_rows_per_step_round_trip(tmp_path: Path) -> None:
    """A .parquet table, one row per step with list columns, rows of two rollouts interleaved and out of step
    order: grouped by rollout_id, ordered by step, equal to the input arrays."""
    first, second = _arrays(1, 3), _arrays(2, 2)
    rows = [("r1", 2, 0), ("r2", 1, 1), ("r1", 0, 0), ("r2", 0, 1), ("r1", 1, 0)]  # (rollout, step, which)
    data = (first, second)
    table = pyarrow.table({
        "rollout_id": [r for r, _, _ in rows], "step": [s for _, s, _ in rows],
        "embeddings": [data[w][0][s].tolist() for _, s, w in rows],
        "actions": [data[w][1][s].tolist() for _, s, w in rows],
        "success": [w == 0 for _, _, w in rows], "split": ["test"] * len(rows), "task": ["sorting"] * len(rows)})
    pyarrow.parquet.write_table(table, tmp_path / "steps.parquet")
    convert("generic", tmp_path / "steps.parquet", tmp_path / "out", ConvertOptions())
    converted = read_converted(tmp_path / "out")
    assert sorted(converted) == ["steps.parquet#r1", "steps.parquet#r2"]
    for name, (embeddings, actions), success in (("r1", first, True), ("r2", second, False)):
        split, rollout = converted[f"steps.parquet#{name}"]
        # h: the paper's for Sorting
        assert (split, rollout.success, rollout.task, rollout.exec_steps) == ("test", success, "sorting", 4)
        assert np.array_equal(rollout.embeddings, embeddings) and np.array_equal(rollout.actions, actions)


def test_pickled_list_of_dicts_round_trip_and_custom_keys(tmp_path: Path) -> None:
    """A pickled list of per-rollout dicts under other key names (the --*-key options of the CLI)."""
    runs = [(*_arrays(3, 5), True, "calibration"), (*_arrays(4, 2), False, "test"), (*_arrays(5, 3), True, "test")]
    content = [{"obs": e, "samples": a, "ok": int(ok), "part": split, "name": f"ep{i}", "other": "ignored"}
               for i, (e, a, ok, split) in enumerate(runs)]
    with (tmp_path / "runs.pkl").open("wb") as stream:
        pickle.dump(content, stream)
    out = tmp_path / "out"
    assert main(["convert", "generic", str(tmp_path / "runs.pkl"), "-o", str(out), "--task", "sorting",
                 "--embedding-key", "obs", "--actions-key", "samples", "--success-key", "ok", "--split-key", "part",
                 "--rollout-key", "name", "--channels", "0:1"]) == 0
    converted = read_converted(out)
    assert sorted(converted) == ["runs.pkl#ep0", "runs.pkl#ep1", "runs.pkl#ep2"]
    for i, (embeddings, actions, success, split) in enumerate(runs):
        bag_split, rollout = converted[f"runs.pkl#ep{i}"]
        assert (bag_split, rollout.success, rollout.task, rollout.exec_steps) == (split, success, "sorting", 4)
        assert np.array_equal(rollout.embeddings, embeddings) and np.array_equal(rollout.actions, actions[..., :1])


@needs_observation_only
@pytest.mark.parametrize("suffix", [".npz", ".parquet", ".pkl"])
def test_observation_only_bags_have_no_action_topic(tmp_path: Path, suffix: str) -> None:
    """Without action batches the bags hold embeddings and events only; h is 1 for an unknown task."""
    embeddings = np.array([[0.5, -1.0], [2.0, 3.0], [4.0, 8.0]], np.float32)
    path = tmp_path / "calibration" / f"obs{suffix}"
    path.parent.mkdir()
    if suffix == ".npz":
        np.savez(path, embeddings=embeddings, success=np.array(True))
    elif suffix == ".parquet":
        pyarrow.parquet.write_table(pyarrow.table({"embeddings": embeddings.tolist(), "success": [True] * 3}), path)
    else:
        path.write_bytes(pickle.dumps([{"embeddings": embeddings, "success": True}]))
    convert("generic", tmp_path, tmp_path / "out", ConvertOptions(control_hz=10.0))
    messages = _messages(tmp_path / "out" / "calibration_rollouts")
    assert [t for t, _ in messages] == [EVENTS_TOPIC, EMBEDDING_TOPIC, EMBEDDING_TOPIC, EMBEDDING_TOPIC, EVENTS_TOPIC]
    assert [list(m.data) for _, m in messages[1:4]] == embeddings.tolist()
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for _, m in messages[1:4]]
    assert np.diff(stamps).tolist() == [100_000_000, 100_000_000]  # h = 1 step of 1 / 10 Hz
    with BagReader(tmp_path / "out" / "calibration_rollouts") as reader:
        assert ACTIONS_TOPIC not in reader.topics
        assert (reader.info.embedding_dim, reader.info.batch_size, reader.info.exec_steps) == (2, 0, 1)


def _npz(path: Path, **arrays: Any) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    defaults = {"embeddings": np.ones((2, 3), np.float32), "actions": np.ones((2, 2, 4, 2), np.float32),
                "success": np.array(True), "split": np.array("test")}
    np.savez(path, **{k: v for k, v in {**defaults, **arrays}.items() if v is not None})
    return path


BAD_NPZ = {  # name: (arrays replaced (None: left out), message after "FILE: rollout 'bad': ")
    "missing embeddings": ({"embeddings": None}, r"no observation embeddings 'embeddings' \(--embedding-key\)"),
    "wrong embedding shape": ({"embeddings": np.ones(2, np.float32)},
                              r"'embeddings' \(--embedding-key\) has shape \(2,\), expected \[T, E\]"),
    "wrong action shape": ({"actions": np.ones((2, 4, 2), np.float32)},
                           r"'actions' \(--actions-key\) has shape \(2, 4, 2\), expected \[T, B, H, D\]"),
    "steps disagree": ({"actions": np.ones((3, 2, 4, 2), np.float32)},
                       r"'embeddings' \(--embedding-key\) has T = 2 steps, 'actions' \(--actions-key\) T = 3"),
    "non-finite embedding": ({"embeddings": np.array([[0, 1, 2], [3, np.nan, 5]], np.float32)},
                             r"'embeddings' \(--embedding-key\) holds NaN/inf \(first at step 1, index \[1, 1\]\)"),
    "non-finite action": ({"actions": np.full((2, 2, 4, 2), np.inf, np.float32)},
                          r"'actions' \(--actions-key\) holds NaN/inf \(first at step 0"),
    "text embeddings": ({"embeddings": np.array([["a", "b", "c"]] * 2)},
                        r"'embeddings' \(--embedding-key\) holds <U1 values, not numbers"),
    "missing label": ({"success": None}, r"no success label 'success' \(--success-key\)"),
    "NaN label": ({"success": np.array(np.nan)}, r"the success label 'success' \(--success-key\) is missing"),
    "label not a bool": ({"success": np.array(0.7)},
                         r"the success label 'success' \(--success-key\) must be a bool \(or 0/1\), got 0.7"),
    "label differs": ({"success": np.array([True, False])}, r"'success' \(--success-key\) differs between steps"),
    "bad split": ({"split": np.array("train")},
                  r"'split' \(--split-key\) is 'train'; expected one of calibration, test"),
    "repeated step": ({"step": np.array([0, 0])}, r"'step' \(--step-key\) repeats a step"),
}


@pytest.mark.parametrize("case", sorted(BAD_NPZ))
def test_each_bad_input_is_named(tmp_path: Path, case: str) -> None:
    arrays, message = BAD_NPZ[case]
    path = _npz(tmp_path / "src" / "bad.npz", **arrays)
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: rollout 'bad': {message}"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1))
    assert not (tmp_path / "out").exists()


def test_mixed_layouts_are_named(tmp_path: Path) -> None:
    """Embedding sizes, batch shapes and the presence of action batches must agree over all files."""
    _npz(tmp_path / "src" / "a.npz")
    other = _npz(tmp_path / "src" / "b.npz", embeddings=np.ones((2, 5), np.float32))
    first = re.escape(f"rollout 'a' of {tmp_path / 'src' / 'a.npz'}")
    with pytest.raises(BagError, match=f"^{re.escape(str(other))}: rollout 'b': 'embeddings' \\(--embedding-key\\) "
                                       f"has E = 5, {first} E = 3: one conversion holds one layout"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1))
    _npz(other, actions=np.ones((2, 3, 4, 2), np.float32))
    with pytest.raises(BagError, match=r"rollout 'b': 'actions' \(--actions-key\) has B, H, D = \(3, 4, 2\), .* "
                                       r"B, H, D = \(2, 4, 2\)"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1))
    _npz(other, actions=None)
    with pytest.raises(BagError, match=r"rollout 'b': 'actions' \(--actions-key\) absent, rollout 'a' .* has action "
                                       "batches: one conversion holds one layout"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1))


def test_npz_rows_must_match_the_rollout_column(tmp_path: Path) -> None:
    path = _npz(tmp_path / "t.npz", rollout_id=np.array(["a", "a", "b"]), embeddings=np.ones((2, 3), np.float32))
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: 'embeddings' \\(--embedding-key\\) has 2 rows, "
                                       r"'rollout_id' \(--rollout-key\) 3: every per-step array has one row per step"):
        convert("generic", path, tmp_path / "out", ConvertOptions(exec_steps=1))


def test_ragged_parquet_lists_are_named(tmp_path: Path) -> None:
    path = tmp_path / "r.parquet"
    batch = [[[0.0], [1.0]]]  # B, H, D = 1, 2, 1
    pyarrow.parquet.write_table(pyarrow.table({
        "rollout_id": ["x", "y", "y"], "embeddings": [[1.0, 2.0], [1.0], [1.0, 2.0]], "actions": [batch] * 3,
        "success": [True] * 3, "split": ["test"] * 3}), path)
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: rollout 'y': 'embeddings' \\(--embedding-key\\) has "
                                       "steps of different lengths"):
        convert("generic", path, tmp_path / "out", ConvertOptions(exec_steps=1))
    pyarrow.parquet.write_table(pyarrow.table({"embeddings": [[1.0, None]], "actions": [batch], "success": [True],
                                               "split": ["test"]}), path)
    with pytest.raises(BagError, match=r"rollout 'r': 'embeddings' .* holds NaN/inf"):
        convert("generic", path, tmp_path / "out", ConvertOptions(exec_steps=1))
    pyarrow.parquet.write_table(pyarrow.table({"embeddings": [[1.0, 2.0]], "actions": [batch], "success": [None],
                                               "split": ["test"]}), path)
    with pytest.raises(BagError, match=r"rollout 'r': the success label 'success' \(--success-key\) is missing"):
        convert("generic", path, tmp_path / "out", ConvertOptions(exec_steps=1))


def test_size_bound_is_checked_before_reading(tmp_path: Path) -> None:
    """--max-mb: a file that declares more than the bound is refused unread; so are the arrays beyond it."""
    big = _npz(tmp_path / "src" / "big.npz", embeddings=np.ones((2, 200_000), np.float32))  # 1.6 MB of arrays
    with pytest.raises(BagError, match=f"^{re.escape(str(big))}: 1.6 MB of arrays, with 0.0 MB converted before, "
                                       r"exceeds --max-mb 1$"):
        convert("generic", tmp_path / "src", tmp_path / "out", ConvertOptions(exec_steps=1, max_mb=1))
    with pytest.raises(BagError, match=r"on disk, with 0.0 MB converted before, exceeds --max-mb 0.001"):
        path = tmp_path / "p" / "x.pkl"
        path.parent.mkdir()
        path.write_bytes(pickle.dumps({"embeddings": np.ones((1, 1000), np.float32), "success": True}))
        convert("generic", path, tmp_path / "out", ConvertOptions(max_mb=0.001))


@pytest.mark.parametrize("content, message", [
    (b"not a zip", r"not a readable \.npz file of arrays \(BadZipFile"),
    (None, r"not a readable \.npz file of arrays \(ValueError: Object arrays cannot be loaded"),
])
def test_unreadable_npz(tmp_path: Path, content: bytes | None, message: str) -> None:
    path = tmp_path / "x.npz"
    if content is None:
        np.savez(path, embeddings=np.array([[1.0]], dtype=object), success=np.array(True))
    else:
        path.write_bytes(content)
    with pytest.raises(BagError, match=f"^{re.escape(str(path))}: {message}"):
        convert("generic", path, tmp_path / "out", ConvertOptions())


def test_cli_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _npz(tmp_path / "src" / "bad.npz", success=None)
    argv = ["convert", "generic", str(tmp_path / "src"), "-o", str(tmp_path / "out"), "--exec-steps", "1"]
    assert main(argv) == 2
    expected = f"fiper convert: {path}: rollout 'bad': no success label 'success' (--success-key)\n"
    assert capsys.readouterr().err == expected
    assert main([*argv, "--success-key", "embeddings"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "must name distinct, non-empty keys" in err
    (tmp_path / "other.txt").write_text("x")
    assert main(["convert", "generic", str(tmp_path / "other.txt"), "-o", str(tmp_path / "out")]) == 2
    assert capsys.readouterr().err == (f"fiper convert: {tmp_path / 'other.txt'}: not one of the generic formats "
                                       "(.npz, .parquet, .pkl, .pickle)\n")
    assert not (tmp_path / "out").exists()


def test_keys_must_be_distinct() -> None:
    with pytest.raises(BagError, match="distinct"):
        Keys(actions="embeddings")
