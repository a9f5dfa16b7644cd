"""The soak's step matching by hand (issue #18: the hour's 52 "unanswered" steps): a batch and its alarm are
matched in either order, and only a batch that waited longer than the expiry is left unanswered."""
from __future__ import annotations

from fiper_ros.bench.soak_bench import StepMatcher


def test_an_alarm_after_its_batch_has_a_positive_latency() -> None:
    matcher = StepMatcher(expire_ns=100)
    assert matcher.batch((1, 0), 10) is None
    assert matcher.alarm((1, 0), 13) == 3
    assert matcher.alarm((1, 0), 14) is None  # matched once; a repeat waits as an alarm without a batch
    assert matcher.expire(1_000) == []


def test_an_alarm_that_overtook_its_batch_is_matched_with_a_negative_latency() -> None:
    # The old meter dropped such an alarm and counted the batch, arriving after it, as unanswered.
    matcher = StepMatcher(expire_ns=100)
    assert matcher.alarm((1, 5), 20) is None
    assert matcher.batch((1, 5), 22) == -2
    assert matcher.expire(1_000) == []


def test_only_batches_older_than_the_expiry_are_stale_and_alarms_without_batch_are_forgotten() -> None:
    matcher = StepMatcher(expire_ns=100)
    matcher.batch((1, 0), 0)
    matcher.batch((1, 1), 50)
    matcher.batch((1, 1), 60)  # a repeated batch keeps its first arrival
    matcher.alarm((2, 0), 0)
    assert matcher.expire(100) == []  # exactly the expiry: not older
    assert matcher.expire(101) == [(1, 0)]
    assert matcher.expire(151) == [(1, 1)]
    assert matcher.batch((2, 0), 200) is None  # the alarm of (2, 0) was forgotten at 101
    assert matcher.expire(301) == [(2, 0)]
