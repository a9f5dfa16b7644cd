"""Messages waiting for their rollout's START."""
from __future__ import annotations

from fiper_ros.runtime.pending import RECENTLY_ENDED, PendingBuffer, StartGate


def test_items_come_back_in_arrival_order_per_rollout() -> None:
    buf: PendingBuffer[str] = PendingBuffer(max_age_ns=10, max_items=8)
    for item, rollout in (("a0", 1), ("b0", 2), ("a1", 1)):
        assert buf.add(rollout, item, 0) == []
    assert len(buf) == 3
    assert buf.take(1) == ["a0", "a1"]
    assert buf.take(1) == []
    assert len(buf) == 1


def test_old_items_expire_and_a_full_buffer_drops_the_oldest() -> None:
    buf: PendingBuffer[str] = PendingBuffer(max_age_ns=10, max_items=2)
    buf.add(1, "old", 0)
    buf.add(2, "new", 8)
    assert buf.add(2, "newer", 9) == ["old"]
    assert buf.expire(19) == ["new"]
    assert buf.take(2) == ["newer"] and len(buf) == 0


def test_the_total_size_is_bounded_not_only_the_count() -> None:
    # Issue #18: 64 waiting messages of 4M floats each would be 1 GB; the size budget drops the oldest.
    buffer: PendingBuffer[str] = PendingBuffer(max_age_ns=10, max_items=64, max_size=10)
    assert buffer.add(1, "a", 0, size=4) == []
    assert buffer.add(2, "b", 0, size=4) == []
    assert buffer.add(2, "c", 0, size=4) == ["a"]      # 12 > 10: the oldest goes
    assert buffer.add(3, "d", 0, size=11) == ["b", "c", "d"]  # bigger than the whole budget: nothing stays
    assert len(buffer) == 0
    assert buffer.add(4, "e", 0, size=3) == [] and buffer.take(4) == ["e"]
    assert buffer.add(5, "f", 0, size=10) == []        # the budget is free again


def test_the_start_gate_releases_a_rollouts_items_in_arrival_order_and_remembers_ended_rollouts() -> None:
    gate: StartGate[str] = StartGate(max_age_ns=10, max_items=8)
    gate.add(2, "2a", 0)
    gate.add(3, "3a", 1)
    gate.add(2, "2b", 2)
    assert gate.start(2) == ["2a", "2b"] and gate.start(2) == [] and len(gate) == 1
    assert not gate.has_ended(2)
    gate.end(2)
    assert gate.has_ended(2) and not gate.has_ended(3)


def test_the_start_gate_remembers_the_last_ended_rollouts_only() -> None:
    gate: StartGate[str] = StartGate()
    for rollout_id in range(1, RECENTLY_ENDED + 2):
        gate.end(rollout_id)
    assert not gate.has_ended(1)  # the oldest is forgotten: memory is bounded
    assert all(gate.has_ended(r) for r in range(2, RECENTLY_ENDED + 2))
