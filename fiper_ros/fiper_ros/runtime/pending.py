"""Messages that arrive before their rollout's START.

Topics are not ordered against each other: a policy's first embedding can overtake the bridge's
RolloutEvent START. Such messages wait here (bounded in count and age) and are processed, in arrival
order, when the START arrives; those that expire are rejected as unknown_rollout.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Generic, TypeVar

Item = TypeVar("Item")


class PendingBuffer(Generic[Item]):
    """Holds items per rollout id for at most ``max_age_ns``, at most ``max_items`` in total."""

    def __init__(self, max_age_ns: int = 1_000_000_000, max_items: int = 64) -> None:
        self.max_age_ns = max_age_ns
        self.max_items = max_items
        self._items: OrderedDict[int, list[tuple[int, Item]]] = OrderedDict()
        self._count = 0

    def add(self, rollout_id: int, item: Item, now_ns: int) -> list[Item]:
        """Keep ``item``; returns the oldest items pushed out when the buffer is full."""
        self._items.setdefault(rollout_id, []).append((now_ns, item))
        self._count += 1
        dropped = []
        while self._count > self.max_items:
            oldest_id = next(iter(self._items))
            entries = self._items[oldest_id]
            dropped.append(entries.pop(0)[1])
            self._count -= 1
            if not entries:
                del self._items[oldest_id]
        return dropped

    def take(self, rollout_id: int) -> list[Item]:
        """Remove and return the items of ``rollout_id`` in arrival order."""
        entries = self._items.pop(rollout_id, [])
        self._count -= len(entries)
        return [item for _, item in entries]

    def expire(self, now_ns: int) -> list[Item]:
        """Remove and return the items older than ``max_age_ns``."""
        expired = []
        for rollout_id in list(self._items):
            entries = self._items[rollout_id]
            keep = [(t, i) for t, i in entries if now_ns - t <= self.max_age_ns]
            expired += [i for t, i in entries if now_ns - t > self.max_age_ns]
            self._count -= len(entries) - len(keep)
            if keep:
                self._items[rollout_id] = keep
            else:
                del self._items[rollout_id]
        return expired

    def __len__(self) -> int:
        return self._count
