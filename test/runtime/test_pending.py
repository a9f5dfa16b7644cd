"""Messages waiting for their rollout's START."""
from __future__ import annotations

from fiper_ros.runtime.pending import PendingBuffer


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
