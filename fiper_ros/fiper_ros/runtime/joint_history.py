"""Which measured joint position belongs to an action batch (joint-velocity ACE, App. A.1).

ACE integrates a batch of joint velocities from the joint position the policy observed when it
sampled them. Topics are not ordered against each other, and a robot keeps publishing
``/joint_states`` while the batch travels (the sim bridge does at every control step once it executes
the chunk), so "the latest joint state to arrive" depends on timing. The rule here depends only on
stamps: the joint state with the latest stamp not after the batch's stamp (the policy node and the sim
bridge stamp both with the observation's stamp, so that is the one observed). The ACE node and the bag
reader both use it, so live scores equal those computed from a bag.

Live, the rule needs the joint states up to the batch's stamp to have been taken before the batch is
scored. An executor that finds a batch and several joint states waiting takes the batch first (one
message per subscription per round), so the ACE node holds its inputs in a :class:`StampGate` until a
joint state stamped at or after the batch's has arrived (per publisher, states arrive in order), or a
wait runs out.
"""
from __future__ import annotations

import bisect
from collections import deque
from collections.abc import Callable, Iterable
from typing import Any

import numpy as np


class JointHistory:
    """The last ``capacity`` joint positions by stamp."""

    def __init__(self, capacity: int = 256) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self.capacity = capacity
        self._stamps: list[int] = []
        self._positions: list[np.ndarray] = []

    def __len__(self) -> int:
        return len(self._stamps)

    def add(self, stamp_ns: int, position: np.ndarray) -> None:
        """Keep ``position`` measured at ``stamp_ns`` (a repeated stamp replaces the earlier one)."""
        index = bisect.bisect_left(self._stamps, stamp_ns)
        if index < len(self._stamps) and self._stamps[index] == stamp_ns:
            self._positions[index] = position
        else:
            self._stamps.insert(index, stamp_ns)
            self._positions.insert(index, position)
        if len(self._stamps) > self.capacity:
            del self._stamps[0], self._positions[0]

    @property
    def latest_stamp(self) -> int | None:
        """The latest stamp kept, None if none."""
        return self._stamps[-1] if self._stamps else None

    def at(self, stamp_ns: int) -> np.ndarray | None:
        """The position with the latest stamp not after ``stamp_ns``; None if every kept one is later."""
        index = bisect.bisect_right(self._stamps, stamp_ns)
        return self._positions[index - 1] if index > 0 else None


class LatestNotAfter:
    """The same rule for a set of stamps known in advance, over joint states offered in any order.

    A bag reader knows every batch's stamp before it reads the joint states (a second pass over the bag), so it
    keeps, per interval between two consecutive batch stamps, only the latest state in it: memory grows with
    the number of batches, never with the number of ``/joint_states`` messages a bag holds.
    """

    def __init__(self, stamps: Iterable[int]) -> None:
        self._stamps = sorted(set(stamps))
        self._latest: list[tuple[int, np.ndarray] | None] = [None] * len(self._stamps)

    def __len__(self) -> int:
        """How many joint states are kept (at most one per stamp asked for)."""
        return sum(entry is not None for entry in self._latest)

    def offer(self, stamp_ns: int, position: np.ndarray) -> None:
        """A joint position measured at ``stamp_ns``; of equal stamps the one offered last is kept, as
        :meth:`JointHistory.add` keeps it."""
        index = bisect.bisect_left(self._stamps, stamp_ns)
        if index == len(self._stamps):
            return  # after every stamp asked for
        entry = self._latest[index]
        if entry is None or stamp_ns >= entry[0]:
            self._latest[index] = (stamp_ns, position)

    def positions(self) -> dict[int, np.ndarray]:
        """Per stamp asked for, the position with the latest stamp not after it (stamps before every
        offered state left out): :meth:`JointHistory.at` over all the states offered."""
        found: dict[int, np.ndarray] = {}
        latest: np.ndarray | None = None
        for stamp, entry in zip(self._stamps, self._latest):
            if entry is not None:
                latest = entry[1]
            if latest is not None:
                found[stamp] = latest
        return found


class StampGate:
    """Inputs in arrival order, each held until the joint states up to its stamp are in, or ``wait_ns`` passed.

    An input without a stamp (a rollout event) waits only for those before it, so events stay in order
    with the batches around them.
    """

    def __init__(self, wait_ns: int) -> None:
        if wait_ns < 0:
            raise ValueError(f"wait_ns must be >= 0, got {wait_ns}")
        self.wait_ns = wait_ns
        self._queue: deque[tuple[int | None, int, Callable[[Any], None], Any]] = deque()

    def __len__(self) -> int:
        return len(self._queue)

    def push(self, handler: Callable[[Any], None], item: Any, stamp_ns: int | None, now_ns: int) -> None:
        """Queue ``handler(item)``; ``stamp_ns`` None: no joint state needed."""
        self._queue.append((stamp_ns, now_ns, handler, item))

    def release(self, latest_state_ns: int | None, now_ns: int) -> list[tuple[Callable[[Any], None], Any, bool]]:
        """The inputs now due, in arrival order, as ``(handler, item, waited_out)``."""
        due = []
        while self._queue:
            stamp, arrived, handler, item = self._queue[0]
            ready = stamp is None or (latest_state_ns is not None and latest_state_ns >= stamp)
            waited_out = not ready and now_ns - arrived >= self.wait_ns
            if not (ready or waited_out):
                break
            self._queue.popleft()
            due.append((handler, item, waited_out))
        return due
