"""``fiper evaluate --dump DIR``: the thresholds per step and first alarms it writes are those the core computes for
the configuration (core.thresholds.fit_threshold, core.combination.fit_joint, core.fusion), value for value."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fiper_ros.cli import main
from fiper_ros.core.combination import GroupCurves, fit_joint
from fiper_ros.core.detectors import info
from fiper_ros.core.fusion import Combine, exceeds, first_alarm, fuse_declared
from fiper_ros.core.rollout import RolloutSet
from fiper_ros.core.thresholds import ThresholdSettings, fit_threshold
from fiper_ros.core.window import aggregate
from fiper_ros.evaluation.cache import ScoreCache, StreamScores
from fiper_ros.evaluation.data import Dataset, load_dataset
from fiper_ros.evaluation.dump import FORMAT, INDEX, VERSION
from fiper_ros.evaluation.methods import METHODS, MethodSettings
from fiper_ros.evaluation.scoring import compute_streams
from fiper_ros.evaluation.sweep import Group

DELTAS = (0.1, 0.3)  # 6 conformal rollouts: +inf thresholds at 0.1
CASES = [
    Group("logpzo", "3", "cp_band"),
    Group("rnd_oe", "max2", "time_varying"),
    Group("ace", "cum", "cp_constant"),
    Group("rnd_oe", "1", "cp_scaled"),
    Group("elapsed", "cum", "cp_constant"),
    Group("fiper", "2/cum", "cp_scaled", "or"),
    Group("fiper", "1/1", "cp_band", "and"),
    Group("pair", "2", "cp_band", "max"),
    Group("pair", "3", "cp_scaled", "kth:2"),
    Group("pair", "1", "cp_band", "and"),
    Group("pair", "cum", "cp_scaled", "or"),
]
COMBINATIONS = {"pair": ("logpzo", "rnd_oe")}


def _aggregated(curves: list[np.ndarray], stream: str, label: str) -> list[np.ndarray]:
    """The core's aggregation of one window label (the elapsed time: always its cumulative sum)."""
    if label == "cum" or info(stream).aggregation == "cumulative":
        return [aggregate(c, "cumulative") for c in curves]
    if label.startswith("max"):
        return [aggregate(c, "max", int(label.removeprefix("max"))) for c in curves]
    return [aggregate(c, "window", int(label)) for c in curves]


def _core(streams: dict[str, StreamScores], group: Group, delta: float, base: ThresholdSettings, steps: int
          ) -> tuple[list[np.ndarray], list[int]]:
    """The thresholds over ``steps`` test steps (one per detector) and first alarms of one configuration, from the
    core's functions alone."""
    detectors = COMBINATIONS.get(group.method) or METHODS[group.method].streams
    labels = group.window.split("/") if len(group.window.split("/")) == len(detectors) else [group.window] * len(detectors)
    curves = {d: {part: _aggregated(getattr(streams[d], part), d, label) for part in ("fit", "conformal", "test")}
              for d, label in zip(detectors, labels)}
    settings = replace(base, kind=group.kind, delta=delta)
    if group.method in COMBINATIONS:
        combine = Combine.parse(group.combine)
        members = [detectors] if combine.joint else [(d,) for d in detectors]
        curves_of = GroupCurves({d: curves[d]["fit"] for d in detectors}, {d: curves[d]["conformal"] for d in detectors})
        fitted = {}
        for member in members:
            joint = fit_joint({"sorting": curves_of}, member, {d: group.kind for d in member},
                              combine.votes(len(member)) if combine.joint else 1, settings)
            fitted.update(joint.thresholds["sorting"])
        thresholds = [fitted[d] for d in detectors]
    else:
        thresholds = [fit_threshold(curves[d]["conformal"], settings, curves[d]["fit"]) for d in detectors]
    alarms = []
    for i in range(len(curves[detectors[0]]["test"])):
        exceeded = [exceeds(curves[d]["test"][i], t.over(curves[d]["test"][i].shape[0]))
                    for d, t in zip(detectors, thresholds)]
        step = first_alarm(fuse_declared(exceeded, group.combine or "and"))
        alarms.append(-1 if step is None else step)
    return [t.over(steps) for t in thresholds], alarms


@pytest.fixture(scope="module")
def dumped(tmp_path_factory: pytest.TempPathFactory, tiny_dataset: Dataset) -> tuple[Path, Path, Dataset]:
    """A ``--dump`` of the tiny data set: its directory, the score cache and the data as the run read it."""
    root = tmp_path_factory.mktemp("dump")
    data = root / "sorting.npz"
    RolloutSet(tiny_dataset.calibration, tiny_dataset.test).save_npz(data)
    argv = ["evaluate", "--data", f"sorting={data}", "--methods", "elapsed,logpzo,rnd_oe,ace,fiper", "--combo",
            "pair=logpzo+rnd_oe", "--tiny", "--windows", "1-3", "--default-window", "2", "--max-pool", "2",
            "--deltas", ",".join(map(str, DELTAS)), "--cache-dir", str(root / "cache"), "--out", str(root / "out"),
            "--dump", str(root / "dump"), "--quiet", "--no-plots"]
    assert main(argv) == 0
    return root / "dump", root / "cache", load_dataset("sorting", [data])


def test_the_dumped_thresholds_and_alarms_are_the_cores(dumped: tuple[Path, Path, Dataset]) -> None:
    directory, cache, dataset = dumped
    index = json.loads((directory / INDEX).read_text())
    assert (index["format"], index["version"], index["deltas"]) == (FORMAT, VERSION, list(DELTAS))
    (entry,) = index["files"]
    path = directory / entry["file"]
    assert (entry["task"], entry["seed"], entry["file"]) == ("sorting", 0, "sorting_seed0.npz")
    assert entry["sha256"] == hashlib.sha256(path.read_bytes()).hexdigest()
    configurations = [Group(c["method"], c["window"], c["threshold"], c["combine"]) for c in index["configurations"]]
    with np.load(path, allow_pickle=False) as arrays:
        ids, lengths, alarms = arrays["rollout_ids"], arrays["lengths"], arrays["alarms"]
        thresholds, rows = arrays["thresholds"], arrays["threshold_rows"]
    assert ids.tolist() == [r.rollout_id for r in dataset.test] and lengths.tolist() == dataset.lengths.tolist()
    assert alarms.shape == (len(configurations), len(DELTAS), len(dataset.test)) and alarms.dtype == np.int32
    assert thresholds.shape == (entry["threshold_rows"], entry["steps"]) and entry["steps"] == dataset.lengths.max()
    assert len({row.tobytes() for row in thresholds}) == len(thresholds)  # each distinct curve once
    settings = MethodSettings.tiny()
    streams, _ = compute_streams(dataset, ["logpzo", "rnd_oe", "ace", "elapsed"], settings, 0, ScoreCache(cache))
    base = settings.calibration_settings(0).threshold_settings()
    infinite = 0
    for group in CASES:
        g = configurations.index(group)
        detectors = index["configurations"][g]["detectors"]
        assert detectors == list(COMBINATIONS.get(group.method) or METHODS[group.method].streams)
        assert (rows[g, :, len(detectors):] == -1).all() and (rows[g, :, :len(detectors)] >= 0).all()
        for d, delta in enumerate(DELTAS):
            expected, first = _core(streams, group, delta, base, thresholds.shape[1])
            for j, gamma in enumerate(expected):
                np.testing.assert_array_equal(thresholds[rows[g, d, j]], gamma, err_msg=f"{group} {delta}")
            assert alarms[g, d].tolist() == first, (group, delta)
            infinite += bool(np.isinf(expected[0]).any())
    assert 0 < infinite < len(CASES) * len(DELTAS)  # +inf thresholds are dumped as such
    assert {c["method"] for c in index["configurations"]} == {"elapsed", "logpzo", "rnd_oe", "ace", "fiper", "pair",
                                                              "fiper_joint", "combined"}
