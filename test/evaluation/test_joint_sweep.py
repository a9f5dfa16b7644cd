"""The sweep of combinations decides exactly as the core's joint threshold (core.combination.fit_joint) and the
votes of core.fusion would, per task and pooled over tasks, for every combine and normalisation kind."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from fiper_ros.core.combination import GroupCurves, fit_joint
from fiper_ros.core.detectors import info
from fiper_ros.core.fusion import Combine, exceeds, first_alarm, fuse_votes
from fiper_ros.core.thresholds import ThresholdSettings
from fiper_ros.core.window import aggregate
from fiper_ros.evaluation.cache import StreamScores
from fiper_ros.evaluation.joint_sweep import joint_sweep
from fiper_ros.evaluation.methods import Combination
from fiper_ros.evaluation.sweep import Group, SweepSettings

SWEEP = SweepSettings(windows=(1, 3), cumulative=True, deltas=(0.1, 0.2, 0.3), max_pool=(2,))
BASE = ThresholdSettings(kind="cp_band", delta=0.1)
COMBINATIONS = (Combination("trio", ("rnd_oe", "logpzo", "elapsed")), Combination("alone", ("logpzo",)),
                Combination("clock", ("elapsed",)))


def _streams(rng: np.random.Generator, scale: float) -> dict[str, StreamScores]:
    """Three streams over the same rollouts: 12 fit, 11 conformal, 15 test (ragged lengths)."""
    lengths = {part: [int(n) for n in rng.integers(4, 14, size=count)]
               for part, count in (("fit", 12), ("conformal", 11), ("test", 15))}
    out = {}
    for name in ("rnd_oe", "logpzo", "elapsed"):
        def curves(part: str, name: str = name) -> list[np.ndarray]:
            if name == "elapsed":
                return [np.ones(n) for n in lengths[part]]
            return [scale * rng.gamma(2.0, size=n) * (1.5 if part == "test" and i % 3 == 0 else 1.0)
                    for i, n in enumerate(lengths[part])]
        out[name] = StreamScores(curves("fit"), curves("conformal"), curves("test"))
    return out


def _aggregated(curves: list[np.ndarray], name: str, label: str) -> list[np.ndarray]:
    if info(name).aggregation == "cumulative" or label == "cum":
        return [aggregate(c, "cumulative") for c in curves]
    if label.startswith("max"):
        return [aggregate(c, "max", int(label.removeprefix("max"))) for c in curves]
    return [aggregate(c, "window", int(label)) for c in curves]


def _expected(streams: dict[str, dict[str, StreamScores]], combination: Combination, label: str, kind: str,
              combine: Combine, delta: float, pooled: bool) -> dict[str, list[int | None]]:
    """First alarms of every task's test rollouts, from the core: fit_joint, thresholds, votes."""
    detectors = combination.detectors
    kinds = {d: info(d).shape or kind for d in detectors}
    settings = ThresholdSettings(kind="cp_band", delta=delta)
    groups = {task: GroupCurves({d: _aggregated(own[d].fit, d, label) for d in detectors},
                                {d: _aggregated(own[d].conformal, d, label) for d in detectors})
              for task, own in streams.items()}
    votes = combine.votes(len(detectors))
    parts = [list(detectors)] if combine.joint or len(detectors) == 1 else [[d] for d in detectors]
    thresholds: dict[str, dict[str, object]] = {task: {} for task in streams}
    for members in parts:
        wanted = groups if pooled else None
        for task in streams:
            chosen = wanted or {task: groups[task]}
            joint = fit_joint({name: GroupCurves({d: g.shape[d] for d in members}, {d: g.conformal[d] for d in members})
                               for name, g in chosen.items()}, members, kinds,
                              votes if combine.joint else 1, settings,
                              combination.equalise if combine.joint else "none", combination.level)
            for d in members:
                thresholds[task][d] = joint.thresholds[task][d]
    out = {}
    for task, own in streams.items():
        tests = {d: _aggregated(own[d].test, d, label) for d in detectors}
        out[task] = [first_alarm(fuse_votes([exceeds(tests[d][i], thresholds[task][d].over(tests[d][i].shape[0]))
                                             for d in detectors], votes))
                     for i in range(len(own[detectors[0]].test))]
    return out


@pytest.mark.parametrize(("pooled", "or_promise"), [(False, "entry"), (True, "entry"), (False, "delta"),
                                                    (True, "delta")])
def test_the_sweep_decides_as_the_core(pooled: bool, or_promise: str) -> None:
    """``or_promise`` ``"delta"``: the OR of the three detectors is decided as the core decides one calibrated at
    delta / 3 (every other combine as at ``"entry"``)."""
    rng = np.random.default_rng(5)
    streams = {"small": _streams(rng, 1.0), "large": _streams(rng, 40.0)}
    sweep = replace(SWEEP, or_promise=or_promise)
    swept = joint_sweep(streams, COMBINATIONS, sweep, dict.fromkeys(streams, BASE), pooled,
                        combines=("max", "kth:2", "and", "or"))
    compared = 0
    for task, result in swept.items():
        assert len(result.groups) == len(set(result.groups))
        for g, group in enumerate(result.groups):
            combination = next(c for c in COMBINATIONS if c.name == group.method)
            combine = Combine.parse(group.combine or "max")
            for d, delta in enumerate(SWEEP.deltas):
                level = delta / 3 if or_promise == "delta" and group.combine == "or" else delta
                expected = _expected(streams, combination, group.window, group.kind, combine, level, pooled)[task]
                assert [None if a < 0 else int(a) for a in result.alarms[g, d]] == expected, (task, group, delta)
                compared += 1
    # trio: 4 labels x 3 kinds (band, scaled, constant) x 4 combines; alone: 4 x 3; clock: its one configuration
    # (cumulative, CP scaled)
    assert compared == 2 * (4 * 3 * 4 + 4 * 3 + 1) * len(SWEEP.deltas)
    ors = [(result.alarms[g], result.infinite[g]) for result in swept.values()
           for g, group in enumerate(result.groups) if group.combine == "or"]
    assert any((alarms >= 0).any() for alarms, _ in ors)  # an OR at delta / 3 compared where it alarms
    assert any(infinite.any() for _, infinite in ors) == (or_promise == "delta")  # 11 conformal: +inf at 0.1 / 3


@pytest.mark.parametrize("pooled", [False, True])
def test_the_sweep_equalises_as_the_core(pooled: bool) -> None:
    """Equalised combinations (quantile at 0.8, tail): the joint combines only, each decided as fit_joint does."""
    rng = np.random.default_rng(8)
    streams = {"small": _streams(rng, 1.0), "large": _streams(rng, 40.0)}
    equalised = tuple(COMBINATIONS[0].equalised(kind, 0.8) for kind in ("quantile", "tail"))
    assert [c.name for c in equalised] == ["trio_quantile", "trio_tail"]
    swept = joint_sweep(streams, equalised, SWEEP, dict.fromkeys(streams, BASE), pooled,
                        combines=("max", "kth:2", "and", "or"))
    compared = 0
    for task, result in swept.items():
        assert {g.combine for g in result.groups} == {"max", "kth:2"}  # equalising applies to one shared factor
        for g, group in enumerate(result.groups):
            combination = next(c for c in equalised if c.name == group.method)
            for d, delta in enumerate(SWEEP.deltas):
                expected = _expected(streams, combination, group.window, group.kind, Combine.parse(group.combine),
                                     delta, pooled)[task]
                assert [None if a < 0 else int(a) for a in result.alarms[g, d]] == expected, (task, group, delta)
                compared += 1
    # quantile: 4 labels x 2 kinds (not the constant shape, which centres the maxima on 0) x 2 combines; tail: 3 kinds
    assert compared == 2 * (4 * 2 * 2 + 4 * 3 * 2) * len(SWEEP.deltas)


def test_groups_name_the_configuration() -> None:
    rng = np.random.default_rng(6)
    swept = joint_sweep({"t": _streams(rng, 1.0)}, COMBINATIONS, SWEEP, {"t": BASE}, False, combines=("max", "kth:2"))
    groups = swept["t"].groups
    assert Group("trio", "3", "cp_scaled", "kth:2") in groups
    assert Group("alone", "cum", "cp_band", "") in groups  # one detector: its own threshold, no combine
    assert [g for g in groups if g.method == "clock"] == [Group("clock", "cum", "cp_scaled", "")]
    assert swept["t"].conformal.tolist() == [11] * len(groups)


def test_pooled_conformal_counts_and_infinite_thresholds() -> None:
    """Per task 11 conformal rollouts cannot serve delta 0.05 (19 needed); pooled over two tasks (22) they can."""
    rng = np.random.default_rng(7)
    streams = {"a": _streams(rng, 1.0), "b": _streams(rng, 2.0)}
    settings = SweepSettings(windows=(2,), cumulative=False, deltas=(0.05, 0.1), max_pool=())
    alone = joint_sweep(streams, COMBINATIONS[:1], settings, dict.fromkeys(streams, BASE), False, combines=("max",))
    pooled = joint_sweep(streams, COMBINATIONS[:1], settings, dict.fromkeys(streams, BASE), True, combines=("max",))
    assert alone["a"].infinite[:, 0].all() and not alone["a"].infinite[:, 1].any()
    assert not pooled["a"].infinite.any() and pooled["a"].conformal.tolist() == [22] * 3  # one group per kind
