"""``fiper evaluate --scores NAME=FILE``: a detector's per-step scores computed elsewhere, evaluated like a built-in
method. A built-in stream's own scores, written to a file and read back as external scores, give that method's
results configuration for configuration, alone and combined; every bad file is refused in one line."""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.core.detectors import info
from fiper_ros.core.rollout import RolloutSet
from fiper_ros.evaluation.cache import RolloutScores, ScoreCache
from fiper_ros.evaluation.data import Dataset, load_dataset
from fiper_ros.evaluation.external import load_scores
from fiper_ros.evaluation.methods import method_of

SWEEP = ["--tiny", "--windows", "1-3", "--default-window", "2", "--deltas", "0.1,0.3", "--max-pool", "2", "--quiet",
         "--no-plots"]

Scores = dict[str, list[float]]


def _by_rollout(dataset: Dataset, raw: RolloutScores) -> Scores:
    """A stream's scores keyed by rollout id (the calibration successes' and the test rollouts')."""
    pairs = [*zip(dataset.calibration_successes, raw.calibration), *zip(dataset.test, raw.test)]
    return {rollout.rollout_id: scores.tolist() for rollout, scores in pairs}


def _configurations(document: dict, method: str) -> dict[tuple[str, str, str], dict]:
    """The sweep entries of ``method`` in results.json by (window, threshold, combine), without the method name."""
    return {(e["window"], e["threshold"], e["combine"]): {k: v for k, v in e.items() if k != "method"}
            for e in document["sweep"] if e["method"] == method}


def test_a_built_in_streams_scores_read_back_as_external_scores_give_its_results(tmp_path: Path,
                                                                                  tiny_dataset: Dataset) -> None:
    data = tmp_path / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    cache = tmp_path / "cache"
    common = ["evaluate", "--data", f"sorting={data}", *SWEEP, "--cache-dir", str(cache)]
    assert main([*common, "--methods", "logpzo", "--no-default-combos", "--out", str(tmp_path / "first")]) == 0
    (entry,) = cache.glob("*.npz")  # logpZO's scores, seed 0, as the engine computed them
    raw = ScoreCache(cache).get(entry.stem)
    assert raw is not None
    scores = tmp_path / "logpzo.json"
    scores.write_text(json.dumps(_by_rollout(load_dataset("sorting", [data]), raw)))
    out = tmp_path / "out"
    assert main([*common, "--methods", "logpzo,elapsed", "--scores", f"lz={scores}", "--combo", "ours=logpzo+elapsed",
                 "--combo", "theirs=external_lz+elapsed", "--out", str(out)]) == 0
    document = json.loads((out / "results.json").read_text())
    assert document["settings"]["combinations"]["combined"] == ["logpzo", "elapsed", "external_lz"]
    assert document["settings"]["external_scores"]["external_lz"]["file"] == str(scores)
    paper = document["protocols"]["paper"]
    for built_in, external in (("logpzo", "external_lz"), ("ours", "theirs")):
        ours, theirs = _configurations(document, built_in), _configurations(document, external)
        assert len(ours) > 10 and ours == theirs, built_in  # every window, threshold kind (and combine), every delta
        for chosen in (paper["selected"], paper["default"]):  # the selected and the default (a method's) configuration
            assert (built_in in chosen) == (external in chosen) and (built_in in chosen or built_in == "ours")
            if built_in in chosen:
                assert ({key: value for key, value in chosen[built_in].items() if key != "guarantee"}
                        == {key: value for key, value in chosen[external].items() if key != "guarantee"})
    assert paper["selected"]["logpzo"]["guarantee"] == "≤ δ"
    assert paper["selected"]["external_lz"]["guarantee"] == "≤ δ if the model of external lz saw no calibration rollout"


def test_npz_and_json_files_give_the_same_scores(tmp_path: Path) -> None:
    scores = {"a": [0.0, 1.5, 2.25], "b-7": [3, 0, 1]}
    (tmp_path / "s.json").write_text(json.dumps(scores))
    np.savez(tmp_path / "s.npz", **{key: np.array(value) for key, value in scores.items()})
    from_json, from_npz = load_scores("mine", tmp_path / "s.json"), load_scores("mine", tmp_path / "s.npz")
    assert from_json.stream == "external_mine" and info(from_json.stream).fitted is False
    assert method_of("external_mine").streams == ("external_mine",)
    for loaded in (from_json, from_npz):
        assert list(loaded.scores) == ["a", "b-7"]
        assert all(loaded.scores[k].dtype == np.float64 and loaded.scores[k].tolist() == v for k, v in scores.items())
    assert from_json.sha256 != from_npz.sha256  # the cache key of the stream: the file's content


def _scores(dataset: Dataset) -> Scores:
    """Valid external scores of ``dataset``: one score >= 0 per policy step of every rollout."""
    return {r.rollout_id: (np.arange(r.length) / r.length).tolist() for r in (*dataset.calibration, *dataset.test)}


def _json(path: Path, scores: object) -> Path:
    path.write_text(json.dumps(scores))
    return path


def _with(change: Callable[[Scores], None]) -> Callable[[Path, Dataset], Path]:
    """A JSON file of the valid scores changed (in place) by ``change``."""
    def write(directory: Path, dataset: Dataset) -> Path:
        scores = _scores(dataset)
        change(scores)
        return _json(directory / "scores.json", scores)
    return write


def _npz_with_nan(directory: Path, dataset: Dataset) -> Path:
    arrays = {key: np.array(value) for key, value in _scores(dataset).items()}
    arrays[dataset.test[1].rollout_id][2] = np.nan
    np.savez(directory / "scores.npz", **arrays)
    return directory / "scores.npz"


def _without(index: int) -> Callable[[Scores], None]:
    def change(scores: Scores) -> None:
        del scores[list(scores)[index]]
    return change


def _set(rollout: int, value: object) -> Callable[[Scores], None]:
    def change(scores: Scores) -> None:
        scores[list(scores)[rollout]] = value  # type: ignore[assignment]
    return change


def _step(rollout: int, step: int, value: float) -> Callable[[Scores], None]:
    def change(scores: Scores) -> None:
        scores[list(scores)[rollout]][step] = value
    return change


@pytest.mark.parametrize(("write", "message"), [
    (_with(_without(-1)), "no scores for rollout {last!r} of task 'sorting'"),
    (_with(_without(0)), "no scores for rollout {calibration[0]!r} of task 'sorting'"),
    (_with(lambda s: s.update({"nobody": [0.0], "nobody-2": [1.0]})),
     "scores of rollout 'nobody' (and 1 more), which is in no task's data"),
    (_with(lambda s: s[next(iter(s))].append(0.5)), "rollout {calibration[0]!r} of task 'sorting' has {steps1} scores "
                                                    "for its {steps0} policy steps"),
    (_with(_step(-1, 3, -0.25)), "rollout {last!r}: the score of step 3 is -0.25; scores must be >= 0"),
    (_npz_with_nan, "rollout {test[1]!r}: the score of step 2 is nan; scores must be finite"),
    (lambda d, _: _json(d / "scores.json", {"a": [1.0, float("inf")]}),
     "rollout 'a': the score of step 1 is inf; scores must be finite"),
    (_with(_set(2, "high")), "rollout {calibration[2]!r}: expected a list of numbers, one score per policy step, got "
                             "\"high\""),
    (_with(_set(2, [[1.0], [2.0]])), "rollout {calibration[2]!r}: expected a list of numbers, one score per policy "
                                     "step, got [[1.0], [2.0]]"),
    (_with(_set(2, [True, False])), "rollout {calibration[2]!r}: expected a list of numbers, one score per policy "
                                    "step, got [true, false]"),
    (_with(_set(2, [])), "rollout {calibration[2]!r}: expected a list of numbers, one score per policy step, got []"),
    (lambda d, _: _json(d / "scores.json", [1, 2]), "expected a JSON object {{rollout_id: [scores]}}, got list"),
    (lambda d, _: _json(d / "scores.json", {}), "no rollouts in the file"),
    (lambda d, _: d / "missing.json", "file not found"),
    (lambda d, _: _json(d / "scores.csv", {}), "expected a .json or .npz file of {{rollout_id: [scores]}}"),
])
def test_bad_external_scores_are_refused_in_one_line(tmp_path: Path, tiny_dataset: Dataset,
                                                     capsys: pytest.CaptureFixture[str],
                                                     write: Callable[[Path, Dataset], Path], message: str) -> None:
    data = tmp_path / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    scores = write(tmp_path, tiny_dataset)
    first = tiny_dataset.calibration[0]
    detail = message.format(test=[r.rollout_id for r in tiny_dataset.test], last=tiny_dataset.test[-1].rollout_id,
                            calibration=[r.rollout_id for r in tiny_dataset.calibration_successes],
                            steps0=first.length, steps1=first.length + 1)
    err = _refused(["--data", f"sorting={data}", "--scores", f"mine={scores}", "--out", str(tmp_path / "out")], capsys)
    assert err == f"fiper evaluate: --scores mine={scores}: {detail}"
    assert not (tmp_path / "out").exists()


def _refused(argv: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """Run ``fiper evaluate``; it must refuse with exit 2 and one line on stderr."""
    assert main(["evaluate", *argv, *SWEEP, "--no-cache"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("fiper evaluate: ") and "Traceback" not in err, err
    return err.strip()


def test_bad_scores_options_are_refused_in_one_line(tmp_path: Path, tiny_dataset: Dataset,
                                                    capsys: pytest.CaptureFixture[str]) -> None:
    data = tmp_path / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    scores = _json(tmp_path / "scores.json", _scores(tiny_dataset))
    given = ["--data", f"sorting={data}", "--out", str(tmp_path / "out")]
    assert _refused([*given, "--scores", str(scores)], capsys) == (
        f"fiper evaluate: --scores expects NAME=FILE (a .json or .npz of {{rollout_id: [scores]}}), got '{scores}'")
    assert _refused([*given, "--scores", f"Mine={scores}"], capsys) == (
        f"fiper evaluate: --scores Mine={scores}: external score name 'Mine' must match [a-z][a-z0-9_]* (it becomes "
        "the stream external_<name>)")
    assert _refused([*given, "--scores", f"a={scores}", "--scores", f"a={scores}"], capsys) == (
        "fiper evaluate: --scores a=... is given twice: one file per name")
    assert _refused([*given, "--combo", "mix=logpzo+external_b"], capsys) == (
        "fiper evaluate: detector 'external_b' reads external scores: give them with --scores b=FILE")
    twice = [*given, "--data", f"again={data}", "--scores", f"mine={scores}"]
    assert _refused(twice, capsys) == (
        f"fiper evaluate: --scores mine={scores}: rollout id {tiny_dataset.calibration[0].rollout_id!r} is in task "
        "'sorting' and in task 'again': external scores need distinct rollout ids")
    assert not (tmp_path / "out").exists()
