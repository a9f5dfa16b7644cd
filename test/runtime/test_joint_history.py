"""The joint position of an action batch: latest stamp not after the batch's, whatever the arrival order."""
from __future__ import annotations

import numpy as np
import pytest

from fiper_ros.runtime.joint_history import JointHistory


def q(value: float) -> np.ndarray:
    return np.full(7, value)


def test_the_latest_stamp_not_after_the_batch_wins_in_any_arrival_order() -> None:
    history = JointHistory()
    for stamp in (300, 100, 200, 400):  # a control step's state (400) arrives before the batch stamped 300
        history.add(stamp, q(stamp))
    assert history.at(300)[0] == 300  # exact stamp
    assert history.at(350)[0] == 300  # between two: the earlier
    assert history.at(10_000)[0] == 400
    assert history.at(99) is None  # every kept one is later
    assert len(history) == 4


def test_a_repeated_stamp_replaces_and_capacity_drops_the_oldest() -> None:
    history = JointHistory(capacity=2)
    history.add(100, q(1.0))
    history.add(100, q(2.0))
    assert len(history) == 1 and history.at(100)[0] == 2.0
    history.add(200, q(3.0))
    history.add(300, q(4.0))
    assert len(history) == 2 and history.at(150) is None and history.at(250)[0] == 3.0
    with pytest.raises(ValueError, match="capacity"):
        JointHistory(capacity=0)
