"""The example supervisor's halt delivery (no DDS): a halt is pending until the service confirms it."""
from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fiper_ros.runtime.halt_delivery import REFUSED, UNANSWERED, UNAVAILABLE, HaltDelivery
from fiper_ros.runtime.supervision import HaltDecision

MS = 1_000_000
TIMEOUT, RETRY = 100 * MS, 50 * MS


def delivery() -> HaltDelivery:
    return HaltDelivery(TIMEOUT, RETRY)


def test_timeout_and_retry_must_be_positive() -> None:
    for timeout, retry in ((0, 1), (1, 0), (-1, 1), (1, -1)):
        with pytest.raises(ValueError, match=r"^reply_timeout_ns and retry_ns must be > 0$"):
            HaltDelivery(timeout, retry)
    assert HaltDelivery(1, 1).pending is None  # one nanosecond each is allowed


def test_nothing_is_due_before_a_decision() -> None:
    d = delivery()
    assert not d.due(0) and not d.timed_out(10**12) and d.error() == ""
    assert d.diagnostic_values() == {"halts_confirmed": "0", "halt_pending": "none", "halt_unavailable": "0",
                                     "halt_refused": "0", "halt_unanswered": "0"}
    for report, name in ((lambda: d.sent(0), "sent"), (lambda: d.replied(True, "", 0), "replied"),
                         (lambda: d.unavailable("/halt", 0), "unavailable")):
        with pytest.raises(RuntimeError, match=rf"^{name}: no halt is pending$"):
            report()


def test_a_confirmed_halt_is_no_longer_pending() -> None:
    d = delivery()
    d.decide(HaltDecision(3, "ALARM: both"), 10 * MS)
    assert d.due(10 * MS)
    d.sent(10 * MS)
    assert not d.due(11 * MS) and d.error() == ""  # the first request in flight is no failure yet
    confirmed = d.replied(True, "rollout 3 halted", 12 * MS)
    assert confirmed is not None and confirmed.decision.rollout_id == 3 and confirmed.attempts == 1
    assert d.pending is None and d.confirmed == 1
    assert not d.due(10**12) and d.error() == ""
    d.decide(HaltDecision(4, "silence"), 20 * MS)  # the next rollout's halt: counted on
    d.sent(20 * MS)
    assert d.replied(True, "rollout 4 halted", 21 * MS) is not None and d.confirmed == 2


def test_a_refused_halt_is_asked_again_after_the_retry_interval_and_reported_until_confirmed() -> None:
    d = delivery()
    d.decide(HaltDecision(3, "ALARM"), 0)
    d.sent(0)
    assert d.replied(False, "brakes busy", 5 * MS) is None
    assert d.failures[REFUSED] == 1
    assert d.error() == "halt of rollout 3 not confirmed after 1 request(s): the halt service refused: 'brakes busy'"
    assert not d.due(5 * MS + RETRY - 1) and d.due(5 * MS + RETRY)
    d.sent(5 * MS + RETRY)
    assert d.error()  # still not confirmed while the second request is in flight
    assert d.replied(False, "still busy", 60 * MS) is None and d.failures[REFUSED] == 2
    assert d.error() == "halt of rollout 3 not confirmed after 2 request(s): the halt service refused: 'still busy'"
    d.sent(60 * MS + RETRY)
    assert d.replied(True, "ok", 120 * MS) is not None and d.error() == "" and d.confirmed == 1


def test_an_unanswered_halt_times_out_and_is_asked_again() -> None:
    d, sent = delivery(), 10**12  # times far from 0: an elapsed time is a difference
    d.decide(HaltDecision(4, "silence"), sent)
    d.sent(sent)
    assert not d.timed_out(sent + TIMEOUT)  # at the timeout exactly it still waits
    assert d.timed_out(sent + TIMEOUT + 1) and d.failures[UNANSWERED] == 1
    assert d.error() == "halt of rollout 4 not confirmed after 1 request(s): no reply within 0.1 s"
    assert not d.timed_out(sent + TIMEOUT + 2)  # counted once
    with pytest.raises(RuntimeError, match=r"^a reply with no request in flight$"):
        d.replied(True, "late", sent + TIMEOUT + 3)  # the caller forgets the request: a late reply is a caller's bug
    assert not d.due(sent + TIMEOUT + RETRY) and d.due(sent + TIMEOUT + 1 + RETRY)


def test_an_unavailable_service_is_counted_and_retried_without_a_request() -> None:
    d = delivery()
    d.decide(HaltDecision(5, "ALARM"), 0)
    d.unavailable("/sim/halt", 0)
    assert d.failures[UNAVAILABLE] == 1 and d.pending is not None and d.pending.attempts == 0
    assert d.error() == "halt of rollout 5 not confirmed after 0 request(s): halt service /sim/halt is not available"
    assert d.diagnostic_values()["halt_pending"] == "5"
    assert not d.due(RETRY - 1) and d.due(RETRY)


def test_a_new_decision_while_one_is_pending_is_the_same_request() -> None:
    d = delivery()
    d.decide(HaltDecision(5, "ALARM"), 0)
    d.unavailable("/sim/halt", 0)
    d.decide(HaltDecision(6, "UNKNOWN for 2 s"), MS)  # due at once, not after the retry interval
    assert d.due(MS) and d.pending is not None and d.pending.decision.rollout_id == 6
    d.sent(MS)
    d.decide(HaltDecision(7, "ALARM"), 2 * MS)
    assert not d.due(2 * MS)  # one request in flight at a time
    confirmed = d.replied(True, "halted", 3 * MS)
    assert confirmed is not None and confirmed.decision.rollout_id == 7 and d.pending is None


@given(st.lists(st.sampled_from(["unavailable", "refused", "unanswered", "tick"]), max_size=40))
@settings(max_examples=200, deadline=None)
def test_a_halt_is_pending_until_a_success_and_asked_at_most_once_per_retry_interval(events: list[str]) -> None:
    d, now, sends = delivery(), 0, []
    d.decide(HaltDecision(1, "ALARM"), now)
    for event in events:
        now += 7 * MS
        if d.timed_out(now):
            continue
        if d.due(now):
            if event == "unavailable":
                d.unavailable("/halt", now)
            else:
                d.sent(now)
                sends.append(now)
        elif d.pending is not None and d.pending.sent_ns is not None and event == "refused":
            d.replied(False, "no", now)
    assert d.pending is not None  # no success was ever said: still pending
    assert sum(d.failures.values()) >= len(sends) - 1  # every request but the one in flight has ended in a failure
    assert all(b - a >= RETRY for a, b in zip(sends, sends[1:]))  # a failed request is repeated no sooner
    assert d.error() or sum(d.failures.values()) == 0
