"""The joint position of an action batch: latest stamp not after the batch's, whatever the arrival order."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from fiper_ros.runtime.joint_history import JointHistory, LatestNotAfter, StampGate


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


def test_the_gate_holds_a_batch_until_a_state_at_its_stamp_and_keeps_events_in_order() -> None:
    gate = StampGate(wait_ns=500)
    seen: list[str] = []
    gate.push(seen.append, "batch 300", 300, now_ns=0)
    gate.push(seen.append, "END", None, now_ns=10)  # an event behind a held batch waits for it
    gate.push(seen.append, "batch 700", 700, now_ns=20)
    assert gate.release(latest_state_ns=None, now_ns=30) == []
    assert gate.release(latest_state_ns=200, now_ns=40) == []  # the states up to 300 are not all in
    due = gate.release(latest_state_ns=300, now_ns=50)
    assert [(item, late) for _, item, late in due] == [("batch 300", False), ("END", False)]
    for handler, item, _ in due:
        handler(item)
    assert seen == ["batch 300", "END"] and len(gate) == 1
    assert gate.release(latest_state_ns=400, now_ns=519) == []  # 499 ns waited
    assert [(item, late) for _, item, late in gate.release(400, now_ns=520)] == [("batch 700", True)]
    assert len(gate) == 0


def test_a_gate_without_wait_releases_everything_at_once() -> None:
    gate = StampGate(wait_ns=0)
    gate.push(print, "a", 100, now_ns=0)
    gate.push(print, "b", None, now_ns=0)
    assert [(item, late) for _, item, late in gate.release(None, now_ns=0)] == [("a", True), ("b", False)]
    with pytest.raises(ValueError, match="wait_ns"):
        StampGate(-1)
    history = JointHistory()
    assert history.latest_stamp is None
    history.add(200, q(1.0))
    history.add(100, q(2.0))
    assert history.latest_stamp == 200


def test_the_lookup_of_known_stamps_keeps_one_state_per_interval() -> None:
    lookup = LatestNotAfter([300, 100, 300])
    for stamp in (50, 90, 100, 250, 200, 301, 10_000):  # three states before 100, two between, two after 300
        lookup.offer(stamp, q(stamp))
    assert len(lookup) == 2  # the 100 and the 250: the others can never be the answer
    assert {stamp: position[0] for stamp, position in lookup.positions().items()} == {100: 100, 300: 250}
    late = LatestNotAfter([100, 200])
    late.offer(150, q(1.0))
    late.offer(150, q(2.0))  # a repeated stamp: the later offer, as JointHistory.add
    assert set(late.positions()) == {200} and late.positions()[200][0] == 2.0


@given(st.lists(st.integers(0, 50), max_size=12), st.lists(st.tuples(st.integers(0, 60), st.integers()), max_size=40))
def test_the_lookup_equals_the_history_of_every_state(queries: list[int], states: list[tuple[int, int]]) -> None:
    history, lookup = JointHistory(capacity=max(1, len(states))), LatestNotAfter(queries)
    for stamp, value in states:
        history.add(stamp, q(value))
        lookup.offer(stamp, q(value))
    assert len(lookup) <= len(set(queries))
    expected = {stamp: history.at(stamp) for stamp in queries if history.at(stamp) is not None}
    found = lookup.positions()
    assert set(found) == set(expected)
    assert all(np.array_equal(found[stamp], expected[stamp]) for stamp in expected)
