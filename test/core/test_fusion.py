"""The fusion of the detectors' decisions: eq. (7)'s AND/OR and the votes of N detectors."""

from __future__ import annotations

import numpy as np
import pytest

from hypothesis import given
from hypothesis import strategies as st

from fiper_ros.core.combine_mode import COMBINES, CombineMode
from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import Combine, alarms_over_rollout, exceeds, first_alarm, fuse, fuse_declared, fuse_votes


def test_comparison_is_strict() -> None:
    assert not exceeds(1.0, 1.0)
    assert exceeds(1.0 + 1e-12, 1.0)


def test_truth_tables() -> None:
    obs = np.array([False, False, True, True])
    act = np.array([False, True, False, True])
    assert np.array_equal(fuse(obs, act, "and"), [False, False, False, True])
    assert np.array_equal(fuse(obs, act, "or"), [False, True, True, True])
    with pytest.raises(ChoiceError, match="combine"):
        fuse(obs, act, "xor")


def test_default_combine_is_and() -> None:
    """Eq. (7)'s AND is the default of every form of the fusion (App. A.4)."""
    obs, act = np.array([True, False, True]), np.array([False, True, True])
    assert fuse(obs, act).tolist() == [False, False, True]
    alarms, first = alarms_over_rollout(np.array([2.0, 0.0, 2.0]), np.ones(3), np.array([0.0, 2.0, 2.0]), np.ones(3))
    assert alarms.tolist() == [False, False, True] and first == 2


def test_first_alarm_is_the_first_nonzero_step_not_the_largest() -> None:
    assert first_alarm(np.array([0.0, 0.5, 1.0])) == 1
    assert first_alarm(np.array([0, 0, 0])) is None


def test_fuse_declared_by_hand() -> None:
    """Two declared detectors: AND by default; one alone: its own decision as bools (an int 0/1 array too);
    none: refused by name."""
    obs, act = np.array([True, True, False]), np.array([True, False, False])
    assert fuse_declared([obs, act]).tolist() == [True, False, False]
    assert fuse_declared([obs, act], "or").tolist() == [True, True, False]
    alone = fuse_declared([np.array([0, 2, 1])])
    assert alone.dtype == bool and alone.tolist() == [False, True, True]
    with pytest.raises(ValueError, match=r"^at least one detector's decision is needed, got 0$"):
        fuse_declared([])


def test_votes_of_three_detectors_by_hand() -> None:
    a = np.array([True, True, False, False, True])
    b = np.array([True, False, True, False, False])
    c = np.array([True, False, False, False, True])
    assert fuse_declared([a, b, c], "and").tolist() == [True, False, False, False, False]
    assert fuse_declared([a, b, c], "or").tolist() == [True, True, True, False, True]
    assert fuse_declared([a, b, c], "max").tolist() == [True, True, True, False, True]
    assert fuse_declared([a, b, c], "kth:2").tolist() == [True, False, False, False, True]
    assert fuse_declared([a, b, c], "kth:3").tolist() == fuse_declared([a, b, c], "and").tolist()
    assert fuse_declared([True, False, True], "kth:2") is True  # scalars stay a Python bool
    with pytest.raises(ChoiceError, match=r"^combine kth:4 needs at least 4 detectors, got 3$"):
        fuse_declared([a, b, c], "kth:4")


def test_the_promised_multiple_of_delta_by_hand() -> None:
    # Proposition 1 at delta per threshold: the union bound makes an OR of N promise N delta, nothing else does
    assert [Combine.parse(c).promised_multiple(3) for c in ("and", "or", "max", "kth:2")] == [1, 3, 1, 1]
    assert Combine.parse("or").promised_multiple(1) == 1


@pytest.mark.parametrize(("text", "mode", "k", "votes"), [("and", "and", 0, 3), ("or", "or", 0, 1), ("max", "max", 0, 1),
                                                         ("kth:2", "kth", 2, 2)])
def test_combine_parse_and_votes(text: str, mode: str, k: int, votes: int) -> None:
    combine = Combine.parse(text)
    assert (combine.mode, combine.k, combine.votes(3), str(combine)) == (mode, k, votes, text)
    if mode == "kth":
        with pytest.raises(ChoiceError, match=r"^combine kth:2 needs at least 2 detectors, got 1$"):
            combine.votes(1)
    else:
        assert combine.votes(1) == 1  # one detector alone decides alone
    assert combine.joint == (mode in ("max", "kth"))


def test_combine_modes_by_hand() -> None:
    assert COMBINES == ("and", "or") and [mode.joint for mode in CombineMode] == [False, False, True, True]
    assert [mode.written for mode in CombineMode] == ["and", "or", "max", "kth:K"]
    assert Combine("or").mode is CombineMode.OR and Combine.parse("kth:2") == Combine(CombineMode.KTH, 2)
    with pytest.raises(ChoiceError, match=r"^or takes no K$"):
        Combine(CombineMode.OR, 2)


@pytest.mark.parametrize(("text", "message"), [
    ("xor", r"^unknown combine 'xor'; expected one of and, or, max, kth:K$"),
    ("kth", r"^combine 'kth': kth:K needs an integer K >= 1 \(e.g. kth:2\)$"),
    ("kth:0", r"^combine 'kth:0': kth:K needs an integer K >= 1"),
    ("kth:x", r"^combine 'kth:x': kth:K needs an integer K >= 1"),
    ("max:2", r"^combine 'max:2': only kth takes a count \(kth:K\)$"),
])
def test_combine_refusals_are_one_line(text: str, message: str) -> None:
    with pytest.raises(ChoiceError, match=message):
        Combine.parse(text)


@given(st.lists(st.lists(st.booleans(), min_size=4, max_size=4), min_size=1, max_size=6), st.integers(1, 6))
def test_fuse_votes_counts_the_exceedances(decisions: list[list[bool]], votes: int) -> None:
    stacked = np.array(decisions)
    expected = [sum(column) >= votes for column in stacked.T]
    assert fuse_votes(list(stacked), votes).tolist() == expected
