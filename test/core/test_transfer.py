"""``--auto-rule transfer`` (:mod:`fiper_ros.core.transfer`, :func:`fiper_ros.core.calibration.auto.transfer_choice`):
the rule by hand (an entry the data cannot feed or whose threshold is +inf at delta is skipped; the prior's order
decides), the prior file (its hash, a modified file refused in one line) and that a failure is never opened."""
from __future__ import annotations

from dataclasses import replace

from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.auto import DELTA_PROMISE, ENTRY_PROMISE, TRANSFER, AutoError, AutoSettings
from fiper_ros.core.calibration import CalibrationSettings, auto_calibrate
from fiper_ros.core.calibration.auto import finite_at_delta, transfer_choice
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.transfer import (INFINITE, NOT_FED, Prior, PriorEntry, PriorError, choose_from_prior,
                                     prior_promise, threshold_delta)

RULE = AutoSettings(rule=TRANSFER, folds=3)
ACE_FIRST = PriorEntry(("rnd_oe", "ace"), "window", {"rnd_oe": 8, "ace": 50}, "cp_band", "or", method="fiper",
                       twa=0.9, tpr=0.95, tnr=0.85, per_task={"a": 0.9, "b": 0.9})
SIGNAL_B = PriorEntry(("signal_b",), "window", {"signal_b": 3}, "cp_constant", method="signal_b", twa=0.8,
                      per_task={"a": 0.7, "b": 0.9})
JOINT = PriorEntry(("signal_a", "signal_b", "elapsed"), "max", {"signal_a": 5, "signal_b": 5}, "cp_scaled", "kth:2",
                   "quantile", 0.8, "combined", 0.7, per_task={"a": 0.7, "b": 0.7})
PRIOR = Prior((ACE_FIRST, SIGNAL_B, JOINT), ("a", "b"), (0,), (0.05, 0.1), {"subset": "all", "statistic": "worst"},
              {"profile": "paper"},
              "hand-made", "fiper evaluate --write-prior p.yaml", "0.1.0")
SIGNALS = ("signal_a", "signal_b", "elapsed", "rnd_oe")


def test_an_entry_the_data_cannot_feed_is_skipped_then_the_first_that_fits_wins() -> None:
    choice = choose_from_prior(PRIOR, SIGNALS, lambda entry: True, RULE, 0.05)
    assert choice.chosen == SIGNAL_B and choice.rank == 2
    assert [(rank, why) for rank, _, why in choice.skipped] == [(1, NOT_FED)]
    # with action batches (ACE fed) the first entry wins
    assert choose_from_prior(PRIOR, (*SIGNALS, "ace"), lambda entry: True, RULE, 0.05).rank == 1


def test_an_entry_infinite_at_delta_is_skipped() -> None:
    choice = choose_from_prior(PRIOR, SIGNALS, lambda entry: entry is not SIGNAL_B, RULE, 0.05)
    assert choice.chosen == JOINT and choice.rank == 3
    assert [(rank, why) for rank, _, why in choice.skipped] == [(1, NOT_FED), (2, INFINITE)]
    assert "above it 1 need a detector the successes cannot feed, 1 have a +inf threshold at delta" in choice.why()
    record = choice.record()
    assert record["rule"] == TRANSFER and record["rank"] == 3 and record["prior"]["content_hash"] == PRIOR.content_hash
    assert record["chosen"] == JOINT.to_dict() and record["prior"]["tasks"] == ["a", "b"]


def test_no_entry_fits_in_one_line() -> None:
    with pytest.raises(PriorError) as error:
        choose_from_prior(PRIOR, ("rnd_oe", "signal_b", "elapsed"), lambda entry: False, RULE, 0.01)
    text = str(error.value)
    assert "\n" not in text and "3 entries 2 need a detector" in text and "1 have a +inf threshold at delta 0.01" in text


@settings(max_examples=40, deadline=None)
@given(st.lists(st.booleans(), min_size=3, max_size=3), st.lists(st.booleans(), min_size=3, max_size=3))
def test_the_rule_takes_the_first_entry_that_fits_and_is_deterministic(fed: list[bool], finite: list[bool]) -> None:
    detectors = [d for d, keep in zip(("ace", "signal_b", "signal_a"), fed) if keep] + ["rnd_oe", "elapsed"]
    finite_of = {id(e): f for e, f in zip(PRIOR.entries, finite)}
    fits = [all(d in detectors for d in e.detectors) and finite_of[id(e)] for e in PRIOR.entries]
    if not any(fits):
        with pytest.raises(PriorError):
            choose_from_prior(PRIOR, detectors, lambda e: finite_of[id(e)], RULE, 0.1)
        return
    choice = choose_from_prior(PRIOR, detectors, lambda e: finite_of[id(e)], RULE, 0.1)
    assert choice.rank == fits.index(True) + 1 and len(choice.skipped) == choice.rank - 1
    assert choose_from_prior(PRIOR, detectors, lambda e: finite_of[id(e)], RULE, 0.1).record() == choice.record()


def test_finite_at_delta_by_hand() -> None:
    base = CalibrationSettings(detectors=("signal_a",), delta=0.05)  # split conformal, half the successes conformal
    # 50 successes: 25 conformal; delta 0.05 needs 19 (ceil(26 x 0.95) = 25 <= 25), 0.03 needs 33
    assert finite_at_delta(SIGNAL_B, [50], base)
    assert not finite_at_delta(SIGNAL_B, [50], CalibrationSettings(detectors=("signal_a",), delta=0.03))
    assert not finite_at_delta(SIGNAL_B, [50, 36], base)  # 18 conformal successes of the second task
    assert finite_at_delta(SIGNAL_B, [50, 36], CalibrationSettings(detectors=("signal_a",), delta=0.06))
    # the authors' plain quantile is finite however few
    assert finite_at_delta(SIGNAL_B, [6], CalibrationSettings(detectors=("signal_a",), delta=0.01, profile="reference"))
    # pooled over the tasks, one quantile of every task's conformal scores: 25 + 18 = 43 >= 33 at delta 0.03;
    # 9 + 9 + 9 = 27 conformal of 18 successes each reach delta 0.05's 19, not 0.03's 33
    pooled = CalibrationSettings(detectors=("signal_a",), delta=0.03, pooled=True)
    assert finite_at_delta(SIGNAL_B, [50, 36], pooled)
    assert finite_at_delta(SIGNAL_B, [18, 18, 18], replace(pooled, delta=0.05))
    assert not finite_at_delta(SIGNAL_B, [18, 18, 18], pooled)


def test_the_prior_file_round_trips_with_its_hash_and_a_modified_one_is_refused(tmp_path: Path) -> None:
    path = PRIOR.save(tmp_path / "prior.yaml")
    again = Prior.load(path)
    assert again == PRIOR and again.content_hash == PRIOR.content_hash
    data = yaml.safe_load(path.read_text())
    assert data["format_version"] == 1 and data["content_hash"] == PRIOR.content_hash
    assert data["entries"][0]["promise"] == "2 delta" and data["entries"][1]["promise"] == "1 delta"
    data["entries"][1]["twa"] = 0.95  # a figure changed by hand
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(PriorError) as error:
        Prior.load(path)
    assert str(error.value) == f"{path}: content hash mismatch (the prior was modified after it was written)"
    path.write_text("entries: [")
    with pytest.raises(PriorError, match=r"not a readable prior"):
        Prior.load(path)
    assert data["selection"]["statistic"] == "worst"
    unknown = Prior(PRIOR.entries, PRIOR.tasks, selection={"subset": "all", "statistic": "luck"})
    with pytest.raises(PriorError) as error:
        Prior.load(unknown.save(path))
    assert str(error.value) == (f"{path}: selection statistic 'luck' is not one this code knows (mean, worst, rank, "
                                "family, smooth)")
    with pytest.raises(PriorError, match=r"selection statistic None is not one"):
        Prior.load(Prior(PRIOR.entries, PRIOR.tasks, selection={"subset": "all"}).save(path))
    path.write_text(yaml.safe_dump({**PRIOR.content(), "format_version": 2}))
    with pytest.raises(PriorError, match=r"not a prior this code reads \(kind 'fiper-transfer-prior', format_version 2; "
                                         r"expected 'fiper-transfer-prior', 1\)"):
        Prior.load(path)


def test_a_prior_entry_keeps_a_promise() -> None:
    with pytest.raises(PriorError, match="keeps no promise"):
        PriorEntry(("rnd_oe",), "window", {"rnd_oe": 5}, "time_varying")
    with pytest.raises(PriorError, match="cannot be calibrated"):
        PriorEntry(("rnd_a",), "window", {"rnd_a": 5}, "cp_band")
    with pytest.raises(PriorError, match="need a combine"):
        PriorEntry(("rnd_oe", "ace"), "window", {"rnd_oe": 5, "ace": 5}, "cp_band")
    with pytest.raises(PriorError, match="applies to a joint combine"):
        PriorEntry(("rnd_oe", "ace"), "window", {"rnd_oe": 5, "ace": 5}, "cp_band", "and", "quantile")
    wrong = {**ACE_FIRST.to_dict(), "promise": "1 delta"}  # an OR of two thresholds promises 2 delta
    with pytest.raises(PriorError, match="promise '1 delta', its combine promises 2 delta"):
        PriorEntry.from_dict(wrong)
    assert ACE_FIRST.label() == "rnd_oe+ace rnd_oe w8, ace w50 cp_band or (2 delta)"
    assert JOINT.settings() == {"detectors": ("elapsed", "signal_a", "signal_b"), "window": 5,
                                "windows": {"signal_a": 5, "signal_b": 5}, "aggregation": "max",
                                "threshold": "cp_scaled", "combine": "kth:2", "equalise": "quantile",
                                "equalise_level": 0.8}


class SealedFailure:
    """A failed rollout that refuses to be opened: anything but its flag raises."""

    success = False

    def __getattr__(self, name: str) -> Any:  # any attribute
        raise AssertionError(f"a failure was opened: its {name!r} was read")


def _successes(count: int, start: int = 0, actions: bool = False) -> list[Rollout]:
    out = []
    for i in range(start, start + count):
        rng = np.random.default_rng(i)
        signals = {"a": 1.0 + 0.1 * rng.random(20), "b": 1.0 + 0.1 * rng.random(20)}
        batch = rng.normal(size=(20, 2, 4, 3)).astype(np.float32) if actions else None
        out.append(Rollout(f"r{i}", "t", "id", rng.normal(size=(20, 4)).astype(np.float32), batch, 1, True,
                           signals=signals))
    return out


def test_transfer_choice_reads_what_the_successes_feed_and_never_a_failure() -> None:
    successes = _successes(12)
    settings = CalibrationSettings(detectors=("signal_a",), delta=0.3, seed=1)
    alone = transfer_choice(successes, settings, RULE, PRIOR).record()
    assert alone["rank"] == 2  # no action batches: ACE cannot be fed
    assert transfer_choice([*successes[:4], SealedFailure(), *successes[4:]], settings, RULE, PRIOR).record() == alone
    with_actions = transfer_choice(_successes(12, actions=True), settings, RULE, PRIOR)
    assert with_actions.rank == 1  # the test can fail: what the successes feed decides
    # 12 successes, 6 conformal: delta 0.1 needs 9, so every entry is +inf there
    with pytest.raises(PriorError, match=r"3 have a \+inf threshold at delta 0.1"):
        transfer_choice(_successes(12, actions=True), CalibrationSettings(delta=0.1), RULE, PRIOR)


def test_auto_calibrate_with_a_prior_calibrates_the_entry_and_stores_the_rank() -> None:
    settings = CalibrationSettings(detectors=("signal_a",), delta=0.3, seed=1)
    calibration, choice = auto_calibrate(_successes(12), settings, RULE, prior=PRIOR)
    assert calibration.settings.detectors == ("signal_b",) and calibration.settings.threshold == "cp_constant"
    assert calibration.settings.window_of("signal_b") == 3 and calibration.settings.shape_folds == 3
    assert calibration.auto == choice.record() and calibration.auto["rank"] == 2
    with pytest.raises(AutoError, match=r"needs a prior"):
        auto_calibrate(_successes(12), settings, RULE)


ENTRY_RULE = AutoSettings(rule=TRANSFER, folds=3, promise=ENTRY_PROMISE)
OR_SIGNALS = PriorEntry(("signal_a", "signal_b"), "window", {"signal_a": 3, "signal_b": 3}, "cp_constant", "or",
                        method="both", twa=0.9, per_task={"a": 0.9, "b": 0.9})


def test_the_delta_promise_splits_an_or_and_only_an_or() -> None:
    assert threshold_delta(OR_SIGNALS, 0.1, DELTA_PROMISE) == pytest.approx(0.05)
    assert threshold_delta(OR_SIGNALS, 0.1, ENTRY_PROMISE) == 0.1
    assert threshold_delta(ACE_FIRST, 0.06, DELTA_PROMISE) == pytest.approx(0.03)
    assert threshold_delta(JOINT, 0.1, DELTA_PROMISE) == 0.1  # one conformal factor: delta already
    assert threshold_delta(SIGNAL_B, 0.1, DELTA_PROMISE) == 0.1
    with pytest.raises(PriorError, match=r"promise 'half'; expected one of entry, delta"):
        threshold_delta(SIGNAL_B, 0.1, "half")
    # 50 successes, 25 conformal: delta 0.08 needs 12, its half 0.04 needs 24 (ceil(26 x 0.96) = 25 <= 25)
    base = CalibrationSettings(detectors=("signal_a",), delta=0.08)
    assert finite_at_delta(OR_SIGNALS, [50], base, DELTA_PROMISE)
    # 36 successes, 18 conformal: enough for 0.08 (12), not for 0.04 (24): the split OR is +inf, the entry's is not
    assert finite_at_delta(OR_SIGNALS, [36], base, ENTRY_PROMISE)
    assert not finite_at_delta(OR_SIGNALS, [36], base, DELTA_PROMISE)
    assert not finite_at_delta(OR_SIGNALS, [36], base)  # the default promise is delta
    assert finite_at_delta(SIGNAL_B, [36], base, DELTA_PROMISE)


def test_the_delta_promise_is_the_transfer_rules_and_is_calibrated_and_stored() -> None:
    with pytest.raises(AutoError, match=r"--auto-promise entry applies to the transfer rule: the proxy-twa rule's "):
        AutoSettings(promise=ENTRY_PROMISE)
    with pytest.raises(AutoError, match=r"auto promise must be one of entry, delta, got 'loose'"):
        AutoSettings(rule=TRANSFER, promise="loose")
    prior = Prior((OR_SIGNALS, SIGNAL_B), ("a", "b"), (0,), (0.05, 0.1), {"subset": "all", "statistic": "mean"})
    settings = CalibrationSettings(detectors=("signal_a",), delta=0.4, seed=1)
    calibration, choice = auto_calibrate(_successes(12), settings, RULE, prior=prior)
    # 12 successes, 6 conformal: the OR's thresholds at 0.2 each need 4, finite: chosen, calibrated at delta / 2
    assert choice.rank == 1 and calibration.settings.delta == pytest.approx(0.2)
    assert calibration.settings.combine == "or" and calibration.auto["threshold_delta"] == pytest.approx(0.2)
    assert calibration.auto["delta"] == 0.4 and calibration.auto["settings"]["promise"] == DELTA_PROMISE
    assert choice.label() == "signal_a+signal_b w3 cp_constant or (2 delta) at delta/2 each"
    assert "its 2 thresholds at delta 0.2 each keep the promise delta 0.4" in choice.why()
    entry_kept, _ = auto_calibrate(_successes(12), settings, ENTRY_RULE, prior=prior)
    assert entry_kept.settings.delta == 0.4 and entry_kept.auto["threshold_delta"] == 0.4
    # at delta 0.24 the split OR's thresholds at 0.12 need 8 conformal successes (ceil(9 x 0.88) = 8), the 6 are
    # too few: the OR is skipped, the single signal (0.24 needs 4) chosen; the entry's own promise keeps the OR
    choice = transfer_choice(_successes(12), replace(settings, delta=0.24), RULE, prior)
    assert choice.chosen == SIGNAL_B and [why for _, _, why in choice.skipped] == [INFINITE]
    assert transfer_choice(_successes(12), replace(settings, delta=0.24), ENTRY_RULE, prior).chosen == OR_SIGNALS


def test_a_prior_says_its_promise_and_an_unknown_one_is_refused(tmp_path: Path) -> None:
    assert prior_promise(PRIOR) == ENTRY_PROMISE  # a prior written before promises were recorded
    ranked = Prior(PRIOR.entries, PRIOR.tasks, selection={"subset": "all", "statistic": "mean", "promise": "delta"})
    assert prior_promise(Prior.load(ranked.save(tmp_path / "p.yaml"))) == DELTA_PROMISE
    odd = Prior(PRIOR.entries, PRIOR.tasks, selection={"subset": "all", "statistic": "mean", "promise": "loose"})
    with pytest.raises(PriorError, match=r"selection promise 'loose' is not one this code knows \(entry, delta\)"):
        Prior.load(odd.save(tmp_path / "p.yaml"))
