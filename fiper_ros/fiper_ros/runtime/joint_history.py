"""Which measured joint position belongs to an action batch (joint-velocity ACE, App. A.1).

ACE integrates a batch of joint velocities from the joint position the policy observed when it
sampled them. Topics are not ordered against each other, and a robot keeps publishing
``/joint_states`` while the batch travels (the sim bridge does at every control step once it executes
the chunk), so "the latest joint state to arrive" depends on timing. The rule here depends only on
stamps: the joint state with the latest stamp not after the batch's stamp (the policy node and the sim
bridge stamp both with the observation's stamp, so that is the one observed). The ACE node and the bag
reader both use it, so live scores equal those computed from a bag.
"""
from __future__ import annotations

import bisect

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

    def at(self, stamp_ns: int) -> np.ndarray | None:
        """The position with the latest stamp not after ``stamp_ns``; None if every kept one is later."""
        index = bisect.bisect_right(self._stamps, stamp_ns)
        return self._positions[index - 1] if index > 0 else None
