"""Grouping an observation's parts (both camera images, proprioception) by their common stamp.

A robot driver (the sim bridge) publishes one observation per policy step as separate messages on
separate topics, all with the same ``header.stamp``. DDS does not order messages across topics, so
a subscriber collects the parts per stamp and has a complete observation once every part arrived.

The buffer of incomplete groups is bounded: when it is full the oldest group is dropped, and a group
that completes drops every older incomplete one (the driver has moved on: those parts are lost or
were rejected). Parts at or before the last completed stamp are stale (a repetition, or a part that
arrived after a newer group completed) and are dropped. Every drop is counted for diagnostics.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Generic, TypeVar

Part = TypeVar("Part")

#: Incomplete groups kept at most (the bridge has one in flight; a few more absorb reordering).
DEFAULT_MAX_PENDING = 8


class ObservationSync(Generic[Part]):
    """Collects parts named by ``keys`` per stamp and returns each group once it is complete."""

    def __init__(self, keys: Sequence[str], max_pending: int = DEFAULT_MAX_PENDING) -> None:
        if not keys or max_pending < 1:
            raise ValueError("need at least one key and max_pending >= 1")
        self.keys = tuple(keys)
        self.max_pending = max_pending
        self._pending: dict[int, dict[str, Part]] = {}
        self.last_complete: int | None = None
        #: Complete groups returned.
        self.completed = 0
        #: Incomplete groups dropped (buffer full, overtaken by a newer complete group, restart).
        self.dropped_partial = 0
        #: Parts dropped because their stamp is at or before the last complete group's.
        self.stale = 0
        #: Parts that replaced an earlier part with the same key and stamp.
        self.duplicates = 0

    def __len__(self) -> int:
        """Number of incomplete groups waiting for parts."""
        return len(self._pending)

    def add(self, stamp: int, key: str, part: Part) -> dict[str, Part] | None:
        """Add one part; returns the complete group ``{key: part}`` of ``stamp`` if this part completed it."""
        if key not in self.keys:
            raise KeyError(f"unknown observation part {key!r}; expected one of {self.keys}")
        if self.last_complete is not None and stamp <= self.last_complete:
            self.stale += 1
            return None
        group = self._pending.get(stamp)
        if group is None:
            if len(self._pending) >= self.max_pending:
                self._drop_before(min(self._pending) + 1)
            group = self._pending[stamp] = {}
        if key in group:
            self.duplicates += 1
        group[key] = part
        if len(group) < len(self.keys):
            return None
        del self._pending[stamp]
        self._drop_before(stamp)
        self.last_complete = stamp
        self.completed += 1
        return group

    def restart(self, stamp: int | None = None) -> None:
        """A new rollout starts at ``stamp``: drop the incomplete groups before it (all without a stamp)
        and forget the last complete stamp (a restarted driver in simulated time starts its stamps again)."""
        self._drop_before(stamp)
        self.last_complete = None

    def _drop_before(self, stamp: int | None) -> None:
        """Drop the incomplete groups stamped before ``stamp`` (all of them for ``None``)."""
        for older in [s for s in self._pending if stamp is None or s < stamp]:
            del self._pending[older]
            self.dropped_partial += 1
