"""The split of data that comes without one (``fiper_ros.core.data_split``): per task, a seeded fraction of the
successes is calibration, every other rollout test; a fraction that leaves a task too few calibration successes for
the default split-conformal calibration is refused with the fraction that would do."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.core.calibration import CalibrationSettings, split_successes
from fiper_ros.core.data_split import (DataSplitError, calibration_count, describe, fewest_calibration_successes,
                                       serves_calibration, smallest_fraction, split_by_task, split_task)
from fiper_ros.core.rollout import Rollout

PROPERTY = settings(max_examples=80, deadline=None, derandomize=True, database=None)


def _rollout(name: str, task: str, success: bool | None) -> Rollout:
    return Rollout(name, task, "id", np.zeros((2, 3)), None, 1, success)


def test_the_fewest_calibration_successes_by_hand() -> None:
    # split_successes, conformal fraction 0.5 (Python rounds half to even): 7 -> 4 conformal, 3 to fit (< 4);
    # 8 -> 4 and 4
    assert [serves_calibration(n) for n in range(10)] == [False] * 8 + [True] * 2
    assert fewest_calibration_successes() == 8
    assert (len(split_successes(8, CalibrationSettings()).conformal), CalibrationSettings().min_rollouts) == (4, 4)
    # round(0.75 * 10) = 8 (0.74: 7); round(0.16 * 48) = 8 (0.15: 7); round(0.84 * 9) = 8 (0.83: 7)
    assert (smallest_fraction(10), smallest_fraction(48), smallest_fraction(9)) == (0.75, 0.16, 0.84)
    assert smallest_fraction(7) is None
    assert calibration_count(45, 0.5) == 22 and calibration_count(47, 0.5) == 24  # 22.5 -> 22, 23.5 -> 24


def test_a_small_split_by_hand() -> None:
    outcomes = [True, False, True, True, None, True, True, True, True, True, True, False, True, True, True, True, True,
                True]  # 15 successes, 2 failures, 1 unknown
    split = split_task("sorting", outcomes, 0.6, 3)  # round(9.0) = 9 successes to calibration
    assert len(split.calibration) == 9 and all(outcomes[i] is True for i in split.calibration)
    assert sorted(split.calibration + split.test) == list(range(len(outcomes)))
    assert (split.successes, split.failures) == (15, 2)
    assert {1, 4, 11} <= set(split.test)
    order = np.random.default_rng([3, 0xB1AF6E5E]).permutation(15)  # crc32(b"sorting")
    successes = [i for i, o in enumerate(outcomes) if o]
    assert split.calibration == tuple(sorted(successes[i] for i in order[:9]))
    assert split.summary() == ("sorting: 18 rollouts (15 successes, 2 failures, 1 without an outcome): calibration 9 "
                               "successes, test 6 successes and 2 failures, 1 without an outcome")
    assert describe(0.6, 3) == ("drawn: per task, calibration fraction 0.6 of its successes (seed 3), every other "
                                "rollout test")


@pytest.mark.parametrize(("successes", "fraction", "message"), [
    (10, 0.5, "task 'stacking': calibration fraction 0.5 draws 5 of its 10 successes; the default split-conformal "
              r"calibration needs at least 8 \(4 conformal, 4 to fit the score models\): a fraction of 0.75 or more "
              "would do$"),
    (48, 0.1, "draws 5 of its 48 successes; .*: a fraction of 0.16 or more would do$"),
    (6, 0.9, "draws 5 of its 6 successes; .*: no fraction below 1 gives 8: collect more successes$"),
    (20, 0.0, r"calibration fraction must be in \(0, 1\), got 0$"),
    (20, 1.0, r"calibration fraction must be in \(0, 1\), got 1$"),
])
def test_a_fraction_that_leaves_too_few_calibration_successes_is_refused(successes: int, fraction: float,
                                                                         message: str) -> None:
    with pytest.raises(DataSplitError, match=message):
        split_task("stacking", [True] * successes + [False] * 3, fraction, 0)


@PROPERTY
@given(successes=st.integers(8, 60), failures=st.integers(0, 20), fraction=st.floats(0.05, 0.95),
       seed=st.integers(0, 2**31), shuffle=st.integers(0, 2**31))
def test_each_tasks_split_is_stratified_and_independent_of_the_others(successes: int, failures: int, fraction: float,
                                                                      seed: int, shuffle: int) -> None:
    rng = np.random.default_rng(shuffle)
    own = [_rollout(f"a{i}", "open", bool(ok))
           for i, ok in enumerate(rng.permutation([True] * successes + [False] * failures))]
    other = [_rollout(f"b{i}", "close", i % 9 != 0) for i in range(200)]  # 177 successes: any fraction serves
    mixed = list(own)
    for rollout in other:  # the other task's rollouts interleaved at random places; the own task's order kept
        mixed.insert(int(rng.integers(0, len(mixed) + 1)), rollout)
    try:
        alone = split_by_task(own, lambda r: r, fraction, seed)["open"]
    except DataSplitError:
        assert not serves_calibration(calibration_count(successes, fraction))
        return
    together = split_by_task(mixed, lambda r: r, fraction, seed)
    assert list(together) == (["open", "close"] if mixed[0].task == "open" else ["close", "open"])
    drawn = together["open"]
    assert [r.rollout_id for r in drawn.calibration] == [r.rollout_id for r in alone.calibration]
    assert len(drawn.calibration) == calibration_count(successes, fraction)
    assert all(r.success for r in drawn.calibration) and all(r.task == "open" for r in drawn.test)
    assert {r.rollout_id for r in drawn.calibration} | {r.rollout_id for r in drawn.test} == {r.rollout_id for r in own}
    assert sum(r.success is False for r in drawn.test) == failures
    assert [r.rollout_id for r in drawn.test] == [r.rollout_id for r in own if r not in drawn.calibration]


def test_another_seed_draws_another_split_and_the_same_seed_the_same() -> None:
    rollouts = [_rollout(f"r{i}", "pick", True) for i in range(40)]
    draws = {seed: tuple(r.rollout_id for r in split_by_task(rollouts, lambda r: r, 0.5, seed)["pick"].calibration)
             for seed in (0, 0, 1, 2)}
    assert len(draws) == 3 and len(set(draws.values())) == 3
    assert draws[0] == tuple(r.rollout_id for r in split_by_task(rollouts, lambda r: r, 0.5, 0)["pick"].calibration)
