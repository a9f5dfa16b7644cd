"""AND/OR fusion, eq. (7)."""

from __future__ import annotations

import numpy as np
import pytest

from fiper_ros.core.fusion import alarms_over_rollout, exceeds, first_alarm, fuse


def test_comparison_is_strict() -> None:
    assert not exceeds(1.0, 1.0)
    assert exceeds(1.0 + 1e-12, 1.0)


def test_truth_tables() -> None:
    obs = np.array([False, False, True, True])
    act = np.array([False, True, False, True])
    assert np.array_equal(fuse(obs, act, "and"), [False, False, False, True])
    assert np.array_equal(fuse(obs, act, "or"), [False, True, True, True])
    with pytest.raises(ValueError, match="combine"):
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
    any other number: refused by name (mutants of #19's code that no test saw)."""
    from fiper_ros.core.fusion import fuse_declared  # noqa: PLC0415

    obs, act = np.array([True, True, False]), np.array([True, False, False])
    assert fuse_declared([obs, act]).tolist() == [True, False, False]
    assert fuse_declared([obs, act], "or").tolist() == [True, True, False]
    alone = fuse_declared([np.array([0, 2, 1])])
    assert alone.dtype == bool and alone.tolist() == [False, True, True]
    with pytest.raises(ValueError, match=r"^one or two detectors' decisions expected, got 3$"):
        fuse_declared([obs, act, obs])
