"""``--auto`` (:mod:`fiper_ros.core.auto`, :mod:`fiper_ros.core.calibration.auto`): the rule by hand, the failure
proxies, the candidate budget, determinism for a seed, and that a failure is never opened."""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.auto import (PROXIES, AutoError, AutoSettings, Candidate, EmbeddingSpread, TaskScores,
                                 candidates, choose, detector_sets, make_proxy)
from fiper_ros.core.calibration import CalibrationError, CalibrationSettings, load_calibration
from fiper_ros.core.calibration.auto import auto_calibrate, available_detectors, choose_configuration
from fiper_ros.core.calibration_file import CALIBRATION_FILE
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.thresholds import ThresholdSettings

ONE = AutoSettings(windows=(1,), kinds=("cp_constant",), proxies=("stall",), folds=4)


def test_the_rule_by_hand() -> None:
    # Four identical successes (peak 1) per detector: every inner quantile is k = 1 and no held-out success exceeds
    # it (strict). The stall proxies (length 6) of signal_a first exceed k at step 2 (caught 1 - 2/6), those of
    # signal_b at step 4 (1 - 4/6). Each kind's credit is relative to the best candidate's: a scores
    # 0.5 (1 - 0) + 0.5 (2/3) / (2/3) = 1, b 0.5 + 0.5 (1/3) / (2/3) = 0.75. Their joint combinations under CP
    # constant shapes (every peak 1: offset 1) alarm with a (max: the earlier detector) or with b (kth:2: both
    # must exceed) and score the same; a tie goes to fewer detectors.
    success = np.ones(4)
    data = TaskScores({"signal_a": [success] * 4, "signal_b": [success] * 4},
                      {"signal_a": [np.array([1.0, 1.0, 5.0, 5.0, 5.0, 5.0])] * 4,
                       "signal_b": [np.array([1.0, 1.0, 1.0, 1.0, 5.0, 5.0])] * 4}, ("stall",) * 4, (0, 1, 2, 3))
    choice = choose({"t": data}, ["signal_b", "signal_a"], ONE, ThresholdSettings(delta=0.1), seed=0)
    both = ("signal_a", "signal_b")
    assert [s.candidate for s in choice.ranking] == [Candidate(("signal_a",), 1, "cp_constant"),
                                                      Candidate(both, 1, "cp_constant", "max"),
                                                      Candidate(("signal_b",), 1, "cp_constant"),
                                                      Candidate(both, 1, "cp_constant", "kth:2")]
    assert [s.false_alarms for s in choice.ranking] == [0.0] * 4
    assert [s.caught for s in choice.ranking] == [{"stall": pytest.approx(2 / 3)}] * 2 + \
        [{"stall": pytest.approx(1 / 3)}] * 2
    assert [s.score for s in choice.ranking] == [pytest.approx(1.0)] * 2 + [pytest.approx(0.75)] * 2


def test_a_proxy_whose_own_success_alarms_earns_nothing() -> None:
    # Six successes of peak 1 but one of peak 1.5; every proxy exceeds any k from step 2 of 6. The odd success is
    # held out once, against k = 1 (the others): it alarms, and its proxy, although above k, is not credited.
    successes = [np.ones(4)] * 5 + [np.array([1.0, 1.5, 1.0, 1.0])]
    proxy = np.array([1.0, 1.0, 5.0, 5.0, 5.0, 5.0])
    data = TaskScores({"signal_a": successes}, {"signal_a": [proxy] * 6}, ("stall",) * 6, tuple(range(6)))
    settings = AutoSettings(windows=(1,), kinds=("cp_constant",), proxies=("stall",), folds=6)
    best = choose({"t": data}, ["signal_a"], settings, ThresholdSettings(delta=0.1), seed=0).ranking[0]
    assert best.false_alarms == pytest.approx(1 / 6)
    assert best.caught == {"stall": pytest.approx(5 / 6 * 2 / 3)}  # unpaired it would be 2/3


def test_the_detector_that_catches_the_proxies_earlier_wins_and_ties_go_to_fewer_detectors() -> None:
    # signal_a's proxies exceed at step 1, signal_b's at step 4: a wins; a's successes are noisy but a held-out
    # success never exceeds the others' quantile more often than b's does (both have the same peaks).
    rng = np.random.default_rng(0)
    successes = {d: [1.0 + 0.01 * rng.random(8) for _ in range(8)] for d in ("signal_a", "signal_b")}
    early, late = np.r_[1.0, np.full(9, 9.0)], np.r_[np.ones(4), np.full(6, 9.0)]
    proxies = {"signal_a": [early] * 8, "signal_b": [late] * 8}
    data = TaskScores(successes, proxies, ("stall",) * 8, tuple(range(8)))
    settings = AutoSettings(windows=(1,), kinds=("cp_constant", "cp_band"), combines=("max",), proxies=("stall",))
    choice = choose({"t": data}, ["signal_a", "signal_b"], settings, ThresholdSettings(delta=0.1), seed=0)
    assert choice.chosen.detectors == ("signal_a",)
    labels = [s.candidate.label() for s in choice.ranking]
    assert labels.index("signal_a w1 cp_constant") < labels.index("signal_b w1 cp_constant")


def test_candidate_sets_and_the_budget() -> None:
    assert detector_sets(["elapsed", "rnd_oe", "signal_x"]) == [
        ("rnd_oe",), ("elapsed",), ("signal_x",), ("rnd_oe", "elapsed", "signal_x"), ("rnd_oe", "signal_x")]
    settings = AutoSettings(windows=(1, 5), kinds=("cp_band", "cp_constant"), combines=("max", "kth:2", "kth:3"))
    pool = candidates(["rnd_oe", "elapsed"], settings)
    # rnd_oe: 2 windows x 2 kinds; elapsed alone: its one (cumulative, CP constant); the pair: 2 windows x 2 kinds
    # (both have a shape) x max and kth:2 (kth:3 needs three detectors)
    assert len(pool) == 4 + 1 + 8
    assert Candidate(("elapsed",), 1, "cp_constant") in pool
    assert {c.kind for c in pool if len(c.detectors) == 2} == {"cp_band", "cp_constant"}
    with pytest.raises(AutoError, match=r"^13 candidate configurations exceed the auto budget of 12 \(--auto-budget\)"):
        candidates(["rnd_oe", "elapsed"], AutoSettings(windows=(1, 5), kinds=("cp_band", "cp_constant"),
                                                        combines=("max", "kth:2", "kth:3"), budget=12))
    with pytest.raises(AutoError, match="joint"):
        AutoSettings(combines=("and",))
    with pytest.raises(AutoError, match="kinds"):
        AutoSettings(kinds=("time_varying",))



def test_the_windows_are_sorted_and_distinct_whoever_builds_the_settings() -> None:
    """A caller of the core gets the candidates ``--auto-windows`` gives (the CLI's list parser sorted; the settings
    kept the order given, so a fixed-aggregation detector was tried with the first window, not the smallest)."""
    given = AutoSettings(windows=(5, 1, 5), kinds=("cp_band",), combines=("max",))
    assert given.windows == (1, 5) and given == AutoSettings(windows=(1, 5), kinds=("cp_band",), combines=("max",))
    assert candidates(["rnd_oe", "elapsed"], given) == [
        Candidate(("rnd_oe",), 1, "cp_band"), Candidate(("rnd_oe",), 5, "cp_band"),
        Candidate(("elapsed",), 1, "cp_constant"),
        Candidate(("rnd_oe", "elapsed"), 1, "cp_band", "max"), Candidate(("rnd_oe", "elapsed"), 5, "cp_band", "max")]


@given(st.lists(st.integers(1, 60), min_size=1, max_size=12))
def test_auto_windows_of_any_order_are_one_setting(windows: list[int]) -> None:
    assert AutoSettings(windows=windows).windows == tuple(sorted(set(windows)))
    assert AutoSettings(windows=windows) == AutoSettings(windows=windows[::-1])

def _rollout(index: int, length: int = 20, *, success: bool | None = True, signals: dict | None = None) -> Rollout:
    rng = np.random.default_rng(index)
    embeddings = rng.normal(size=(length, 3)).astype(np.float32)
    actions = rng.normal(size=(length, 2, 4, 2)).astype(np.float32)
    steps = np.arange(length, dtype=np.float64)
    return Rollout(f"r{index}", "task", "id", embeddings, actions, 2, success, metadata={"q": steps[:, None]},
                   signals=signals if signals is not None else {"a": steps, "b": 2 * steps})


def test_proxies_by_hand() -> None:
    rollout = _rollout(1)
    spread = EmbeddingSpread(np.array([3.0, 4.0, 0.0]))
    assert spread.total == 5.0
    stall = make_proxy(rollout, "stall", np.random.default_rng(0), spread, 30, 1.0)
    onset = int(np.argmax(np.diff(stall.signals["a"]) == 0))  # the first repeated step
    assert stall.length == 30 and stall.success is None and stall.rollout_id == "r1~stall"
    np.testing.assert_array_equal(stall.signals["a"], np.r_[np.arange(onset + 1), np.full(30 - onset - 1, onset)])
    np.testing.assert_array_equal(stall.embeddings[onset:], np.repeat(rollout.embeddings[onset:onset + 1], 30 - onset, 0))
    np.testing.assert_array_equal(stall.metadata["q"][:, 0], stall.signals["a"])  # per-step metadata follows
    assert 6 <= onset < 14  # in [0.3 T, 0.7 T)
    skip = make_proxy(rollout, "skip", np.random.default_rng(0), spread, 30, 1.0)
    assert skip.length == 15  # a quarter of 20 dropped
    kept = skip.signals["a"].astype(int)
    assert np.count_nonzero(np.diff(kept) == 6) == 1 and np.all(np.diff(kept) >= 1)  # one block of 5 dropped
    drift = make_proxy(rollout, "drift", np.random.default_rng(0), spread, 30, 0.5)
    moved = np.linalg.norm(drift.embeddings - rollout.embeddings, axis=1)
    first = int(np.argmax(moved > 0))
    assert np.all(moved[:first] == 0) and moved[-1] == pytest.approx(2.5, rel=1e-5)  # 0.5 x the total spread
    assert np.all(np.diff(moved[first - 1:]) > 0)  # growing linearly from the onset
    steps = drift.embeddings - rollout.embeddings
    np.testing.assert_allclose(steps[-1] / np.linalg.norm(steps[-1]), steps[first] / np.linalg.norm(steps[first]),
                               rtol=1e-5)  # one direction
    with pytest.raises(AutoError, match="unknown proxy"):
        make_proxy(rollout, "wobble", np.random.default_rng(0), spread, 30, 1.0)
    assert PROXIES == ("stall", "drift", "skip")


class SealedFailure:
    """A failed rollout that refuses to be opened: anything but its flag raises."""

    success = False

    def __getattr__(self, name: str) -> Any:  # any attribute
        raise AssertionError(f"a failure was opened: its {name!r} was read")


def _signal_rollouts(count: int, spike: str | None = None, start: int = 0) -> list[Rollout]:
    """Successes whose signals a and b are noisy and flat; ``spike``: that signal jumps from step 12 on."""
    out = []
    for i in range(start, start + count):
        rng = np.random.default_rng(i)
        signals = {"a": 1.0 + 0.1 * rng.random(24), "b": 1.0 + 0.1 * rng.random(24)}
        if spike is not None:
            signals[spike][12:] += 20.0
        out.append(_rollout(i, 24, signals=signals))
    return out


FAST = CalibrationSettings(detectors=("signal_a",), delta=0.3, seed=4)
SIGNALS = ("signal_a", "signal_b", "elapsed")
AUTO = AutoSettings(windows=(1, 3), folds=3)


def _choose(rollouts: Sequence[Any]) -> dict[str, Any]:
    return choose_configuration(rollouts, FAST, AUTO, SIGNALS).record()


def test_auto_is_deterministic_for_a_seed_and_never_opens_a_failure() -> None:
    successes = _signal_rollouts(14)
    alone = _choose(successes)
    assert _choose(successes) == alone  # deterministic
    # failures interleaved, sealed: the choice is the same and none is opened
    assert _choose([*successes[:5], SealedFailure(), *successes[5:], SealedFailure()]) == alone
    # the same failures (b jumps) read as successes would change it: the test can fail
    failures = _signal_rollouts(14, spike="b", start=100)
    flipped = [Rollout(r.rollout_id, r.task, r.scenario, r.embeddings, r.actions, r.exec_steps, True,
                       signals=r.signals) for r in failures]
    assert _choose([*successes, *flipped]) != alone
    assert choose_configuration(successes, CalibrationSettings(detectors=("signal_a",), delta=0.3, seed=5), AUTO,
                                SIGNALS).record() != alone  # another seed: another split and proxies


def test_available_detectors() -> None:
    rollouts = [_rollout(0), _rollout(1, signals={"a": np.zeros(20)})]
    assert available_detectors(rollouts) == ("rnd_oe", "logpzo", "pca_kmeans", "progress", "ace", "consistency",
                                             "signal_a", "elapsed")
    without = [Rollout("x", "task", "id", np.zeros((5, 3)), None, 1, True)]
    assert available_detectors(without) == ("rnd_oe", "logpzo", "pca_kmeans", "progress", "elapsed")


def test_auto_calibrate_stores_the_choice_and_refuses_what_it_cannot_do(tmp_path: Path) -> None:
    rollouts = _signal_rollouts(14)
    calibration, choice = auto_calibrate(rollouts, FAST, AUTO, SIGNALS)
    assert calibration.settings.detectors == choice.chosen.detectors
    assert calibration.settings.threshold == choice.chosen.kind and calibration.settings.shape_folds == AUTO.folds
    calibration.save(tmp_path / "c")
    loaded = load_calibration(tmp_path / "c")
    assert loaded.auto == choice.record() and loaded.auto["rule"] == "proxy-twa" and loaded.auto["version"] == 1
    assert loaded.auto["chosen"] == choice.chosen.to_dict() and len(loaded.auto["top"]) == 10
    assert loaded.content_hash == calibration.content_hash
    path = tmp_path / "c" / CALIBRATION_FILE
    data = yaml.safe_load(path.read_text())
    data["auto"]["chosen"]["window"] = 99  # the record is covered by the content hash
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(CalibrationError, match="content hash mismatch"):
        load_calibration(tmp_path / "c")
    with pytest.raises(AutoError, match=r"--split split\), not --split same"):
        choose_configuration(rollouts, CalibrationSettings(detectors=("signal_a",), split="same"), AUTO, SIGNALS)
    with pytest.raises(AutoError, match="at least 4 successful rollouts of task 'task', got 3"):
        choose_configuration(rollouts[:3], FAST, AUTO, SIGNALS)


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**16), count=st.integers(4, 9), reverse=st.booleans())
def test_scores_are_rates_and_the_choice_ignores_the_order_of_the_detectors(seed: int, count: int,
                                                                            reverse: bool) -> None:
    rng = np.random.default_rng(seed)
    names = ["signal_a", "signal_b", "elapsed"]
    lengths = rng.integers(5, 12, count)
    successes = {d: [rng.random(n) for n in lengths] for d in names}
    successes["elapsed"] = [np.ones(n) for n in lengths]
    kinds = ("stall", "skip")
    proxies = {d: [rng.random(int(n) + 3) * 3 for n in lengths for _ in kinds] for d in names}
    proxies["elapsed"] = [np.ones(int(n) + 3) for n in lengths for _ in kinds]
    data = TaskScores(successes, proxies, kinds * count, tuple(i for i in range(count) for _ in kinds))
    auto = AutoSettings(windows=(1, 2), combines=("max", "kth:2"), proxies=kinds, folds=3, repeats=2)
    base = ThresholdSettings(delta=0.2)
    choice = choose({"t": data}, names, auto, base, seed)
    assert all(0.0 <= s.score <= 1.0 and 0.0 <= s.false_alarms <= 1.0 for s in choice.ranking)
    assert all(0.0 <= v <= 1.0 for s in choice.ranking for v in s.caught.values())
    again = choose({"t": data}, names[::-1] if reverse else names, auto, base, seed)
    assert again.record() == choice.record()


MARGIN_ONE = AutoSettings(rule="margin", windows=(1,), kinds=("cp_constant",), folds=4)


def _margin_choice(successes: dict[str, list[np.ndarray]], settings: AutoSettings = MARGIN_ONE,
                   delta: float = 0.2) -> Any:
    return choose({"t": TaskScores(successes)}, sorted(successes), settings, ThresholdSettings(delta=delta), seed=3)


@settings(max_examples=25, deadline=None)
@given(scale=st.floats(0.01, 100.0), offset=st.floats(-50.0, 50.0))
def test_the_margin_is_in_units_of_the_successes_spread(scale: float, offset: float) -> None:
    # signal_b is signal_a moved and scaled: the threshold and every success move with it, so the gap in units of
    # the per-step spread (and the held-out false alarms) are the same; the tie goes to the candidate order.
    rng = np.random.default_rng(7)
    a = [rng.normal(size=12) for _ in range(12)]
    choice = _margin_choice({"signal_a": a, "signal_b": [offset + scale * s for s in a]})
    first, second = (s for s in choice.ranking if len(s.candidate.detectors) == 1)
    assert first.caught["margin"] == pytest.approx(second.caught["margin"], rel=1e-9, abs=1e-9)
    assert first.false_alarms == second.false_alarms
    assert np.isfinite(first.caught["margin"]) and first.score == -first.caught["margin"]


def test_the_margin_prefers_the_threshold_closest_to_the_successes_band() -> None:
    # Same per-step noise, but every success of signal_b has one spike of +8 at its own step: its rollout maxima
    # (so its threshold) sit far above its typical step, while signal_a's threshold sits a spread or two above it.
    rng = np.random.default_rng(1)
    a = [rng.normal(size=16) for _ in range(12)]
    b = [s + 8.0 * (np.arange(16) == i) for i, s in enumerate(a)]
    choice = _margin_choice({"signal_a": a, "signal_b": b})
    assert choice.chosen.detectors == ("signal_a",)
    singles = [s for s in choice.ranking if len(s.candidate.detectors) == 1]
    assert singles[0] == choice.ranking[0] and singles[0].caught["margin"] < singles[1].caught["margin"]
    assert "smallest margin" in choice.why() and choice.record()["rule"] == "margin"
    assert choice.record()["top"][0]["figures"] == {"margin": pytest.approx(choice.ranking[0].caught["margin"],
                                                                            abs=1e-6)}


def test_a_detector_without_spread_has_an_infinite_margin_and_is_never_chosen() -> None:
    # The elapsed time's curve is the same for every success: no step has a spread, so no gap can be measured.
    rng = np.random.default_rng(2)
    successes = {"elapsed": [np.arange(1.0, 11.0)] * 10, "signal_a": [rng.normal(size=10) for _ in range(10)]}
    choice = _margin_choice(successes)
    assert choice.chosen.detectors == ("signal_a",)
    assert [s.caught["margin"] for s in choice.ranking if s.candidate.detectors == ("elapsed",)] == [np.inf]


def test_the_margin_rule_builds_no_proxy_is_deterministic_and_an_unknown_rule_is_refused() -> None:
    successes = _signal_rollouts(14)
    margin = AutoSettings(rule="margin", windows=(1, 3), folds=3)
    choice = choose_configuration(successes, FAST, margin, SIGNALS)
    assert choice.settings.rule == "margin" and all(set(s.caught) == {"margin"} for s in choice.ranking)
    assert choice.record() == choose_configuration(successes, FAST, margin, SIGNALS).record()
    assert choose_configuration([*successes[:5], SealedFailure(), *successes[5:]], FAST, margin,
                                SIGNALS).record() == choice.record()  # a failure is never opened
    with pytest.raises(AutoError, match="auto rule must be one of proxy-twa, margin, transfer, got 'best'"):
        AutoSettings(rule="best")
