"""Grouping an observation's parts by stamp (the policy node's input side), without DDS."""
from __future__ import annotations

import pytest

from fiper_ros.runtime.observation_sync import ObservationSync

KEYS = ("wrist_rgb", "third_rgb", "proprio")


def test_a_group_completes_in_any_order_and_only_once() -> None:
    sync: ObservationSync[str] = ObservationSync(KEYS)
    assert sync.add(10, "proprio", "p10") is None
    assert sync.add(20, "wrist_rgb", "w20") is None  # the next stamp interleaves
    assert sync.add(10, "third_rgb", "t10") is None
    assert sync.add(10, "wrist_rgb", "w10") == {"proprio": "p10", "third_rgb": "t10", "wrist_rgb": "w10"}
    assert (sync.completed, len(sync), sync.last_complete) == (1, 1, 10)
    assert sync.add(10, "proprio", "again") is None  # a part of a completed stamp is stale
    assert sync.add(5, "proprio", "older") is None
    assert sync.stale == 2
    assert sync.add(20, "third_rgb", "t20") is None and sync.add(20, "proprio", "p20") is not None
    assert (sync.completed, sync.dropped_partial, len(sync)) == (2, 0, 0)


def test_a_complete_group_drops_older_partial_ones() -> None:
    sync: ObservationSync[int] = ObservationSync(KEYS)
    sync.add(10, "wrist_rgb", 1)  # this tick lost its other parts (or they were rejected)
    sync.add(15, "proprio", 1)
    sync.add(30, "proprio", 1)  # a later partial group stays
    for key in KEYS:
        group = sync.add(20, key, 2)
    assert group == dict.fromkeys(KEYS, 2)
    assert (sync.dropped_partial, len(sync)) == (2, 1)


def test_duplicates_replace_and_are_counted() -> None:
    sync: ObservationSync[str] = ObservationSync(("a", "b"))
    sync.add(1, "a", "first")
    sync.add(1, "a", "second")
    assert sync.add(1, "b", "b") == {"a": "second", "b": "b"} and sync.duplicates == 1


def test_the_buffer_is_bounded() -> None:
    sync: ObservationSync[int] = ObservationSync(KEYS, max_pending=3)
    for stamp in range(10):
        sync.add(stamp, "wrist_rgb", stamp)
    assert len(sync) == 3 and sync.dropped_partial == 7
    sync.add(9, "third_rgb", 9)
    assert sync.add(9, "proprio", 9) is not None  # the newest survived


def test_restart_forgets_old_stamps() -> None:
    sync: ObservationSync[int] = ObservationSync(("a",))
    assert sync.add(100, "a", 1) is not None
    assert sync.add(5, "a", 1) is None and sync.stale == 1  # before a restart: stale
    sync.restart(5)  # a restarted driver in simulated time stamps from the beginning again
    assert sync.add(5, "a", 1) is not None
    two: ObservationSync[int] = ObservationSync(("a", "b"))
    two.add(1, "a", 1)
    two.add(7, "a", 1)
    two.restart(5)  # a new rollout from stamp 5: the group at 1 is dropped, the one at 7 may be its first tick
    assert (len(two), two.dropped_partial) == (1, 1)
    two.restart()
    assert (len(two), two.dropped_partial) == (0, 2)


def test_unknown_keys_and_bad_sizes_are_errors() -> None:
    with pytest.raises(KeyError):
        ObservationSync(KEYS).add(1, "depth", 0)
    with pytest.raises(ValueError):
        ObservationSync(KEYS, max_pending=0)
