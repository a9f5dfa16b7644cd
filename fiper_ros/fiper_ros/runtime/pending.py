"""Messages that arrive before their rollout's START: the START gate of the scoring and fusion nodes.

Topics are not ordered against each other: a policy's first embedding can overtake the bridge's
RolloutEvent START. Such messages wait here (bounded in count, in total size and in age) and are
processed, in arrival order, when the START arrives; those that expire are rejected as unknown_rollout.
:class:`StartGate` adds the rollouts that ended recently, so that a late message of one is known as such
at once instead of waiting for a START that never comes.
"""
from __future__ import annotations

from collections import OrderedDict, deque
from typing import Generic, TypeVar

Item = TypeVar("Item")


class PendingBuffer(Generic[Item]):
    """Holds items per rollout id for at most ``max_age_ns``, at most ``max_items`` of total ``size`` at most
    ``max_size`` (e.g. float values: a few huge messages cannot fill the memory)."""

    def __init__(self, max_age_ns: int = 1_000_000_000, max_items: int = 64, max_size: int | None = None) -> None:
        self.max_age_ns = max_age_ns
        self.max_items = max_items
        self.max_size = max_size
        self._items: OrderedDict[int, list[tuple[int, int, Item]]] = OrderedDict()
        self._count = 0
        self._size = 0

    def add(self, rollout_id: int, item: Item, now_ns: int, size: int = 1) -> list[Item]:
        """Keep ``item`` (of ``size``); returns the oldest items pushed out when the buffer is full."""
        self._items.setdefault(rollout_id, []).append((now_ns, size, item))
        self._count += 1
        self._size += size
        dropped = []
        while self._count > self.max_items or (self.max_size is not None and self._size > self.max_size):
            oldest_id = next(iter(self._items))
            entries = self._items[oldest_id]
            _, old_size, old = entries.pop(0)
            dropped.append(old)
            self._count -= 1
            self._size -= old_size
            if not entries:
                del self._items[oldest_id]
        return dropped

    def take(self, rollout_id: int) -> list[Item]:
        """Remove and return the items of ``rollout_id`` in arrival order."""
        entries = self._items.pop(rollout_id, [])
        self._count -= len(entries)
        self._size -= sum(size for _, size, _ in entries)
        return [item for _, _, item in entries]

    def expire(self, now_ns: int) -> list[Item]:
        """Remove and return the items older than ``max_age_ns``."""
        expired = []
        for rollout_id in list(self._items):
            entries = self._items[rollout_id]
            keep = [e for e in entries if now_ns - e[0] <= self.max_age_ns]
            gone = [e for e in entries if now_ns - e[0] > self.max_age_ns]
            expired += [item for _, _, item in gone]
            self._count -= len(gone)
            self._size -= sum(size for _, size, _ in gone)
            if keep:
                self._items[rollout_id] = keep
            else:
                del self._items[rollout_id]
        return expired

    def __len__(self) -> int:
        return self._count


#: How many ended rollouts a :class:`StartGate` remembers.
RECENTLY_ENDED = 16


class StartGate(PendingBuffer[Item]):
    """The START gate of a node: a :class:`PendingBuffer` of the messages whose rollout has not started, which
    :meth:`start` drains in arrival order, and the ids of the last :data:`RECENTLY_ENDED` rollouts that ended."""

    def __init__(self, max_age_ns: int = 1_000_000_000, max_items: int = 64, max_size: int | None = None) -> None:
        super().__init__(max_age_ns, max_items, max_size)
        self._ended: deque[int] = deque(maxlen=RECENTLY_ENDED)

    def start(self, rollout_id: int) -> list[Item]:
        """The rollout's START arrived: remove and return its waiting items in arrival order."""
        return self.take(rollout_id)

    def end(self, rollout_id: int) -> None:
        """The rollout ended: remember it."""
        self._ended.append(rollout_id)

    def has_ended(self, rollout_id: int) -> bool:
        """Whether ``rollout_id`` is one of the rollouts that ended recently."""
        return rollout_id in self._ended
