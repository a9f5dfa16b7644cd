"""Delivery of the example supervisor's halts: a halt is done only when the robot's halt service confirms it.

:mod:`fiper_ros.runtime.supervision` decides *when* to halt; this module sees that the decision reaches the robot.
A halt is pending from its decision until a reply that says ``success``. Every other end of an attempt is a named
failure, counted and kept as the reason the halt is not confirmed: the service is not available (``unavailable``),
it answered ``success`` false (``refused``, with its message) or it did not answer within the reply timeout
(``unanswered``). After a failure the halt is asked again once the retry interval has passed, for as long as it
is pending: an unconfirmed halt is never given up, and the rate of requests is bounded by the interval. One
halt is pending at a time: a halt stops whatever runs, so a new decision while one is pending is the same
request (it replaces the pending one's rollout and reason, and its failures stay on record).

Times are steady-clock nanoseconds (a service's answer is a wall-clock matter, also under simulated time).
"""
from __future__ import annotations

from dataclasses import dataclass

from fiper_ros.runtime.supervision import HaltDecision

#: The ways an attempt to halt ends without a confirmation (the counters' names on ``/diagnostics``).
UNAVAILABLE, REFUSED, UNANSWERED = "unavailable", "refused", "unanswered"
FAILURES = (UNAVAILABLE, REFUSED, UNANSWERED)


@dataclass
class PendingHalt:
    """A decided halt that the halt service has not confirmed yet."""

    decision: HaltDecision
    retry_ns: int
    """The earliest time of the next attempt."""
    attempts: int = 0
    """Requests sent for it (an unavailable service takes none)."""
    sent_ns: int | None = None
    """When the request in flight was sent; None: none in flight."""
    failure: str = ""
    """Why the last attempt did not confirm it (``""``: no attempt has failed)."""


class HaltDelivery:
    """Tracks the pending halt; the node sends the requests when :meth:`due` says so and reports how each ended."""

    def __init__(self, reply_timeout_ns: int, retry_ns: int) -> None:
        if reply_timeout_ns <= 0 or retry_ns <= 0:
            raise ValueError("reply_timeout_ns and retry_ns must be > 0")
        self.reply_timeout_ns = reply_timeout_ns
        self.retry_ns = retry_ns
        self.pending: PendingHalt | None = None
        self.confirmed = 0
        self.failures = dict.fromkeys(FAILURES, 0)

    def decide(self, decision: HaltDecision, now_ns: int) -> None:
        """A new halt decision: pending from now, due at once unless a request for the pending one is in flight."""
        if self.pending is None:
            self.pending = PendingHalt(decision, now_ns)
        else:
            self.pending.decision = decision
            self.pending.retry_ns = min(self.pending.retry_ns, now_ns)

    def due(self, now_ns: int) -> bool:
        """Whether a request should be sent now: a halt is pending, none is in flight and its retry time came."""
        pending = self.pending
        return pending is not None and pending.sent_ns is None and now_ns >= pending.retry_ns

    def sent(self, now_ns: int) -> None:
        """A request for the pending halt was sent."""
        pending = self._in_hand("sent")
        pending.attempts += 1
        pending.sent_ns = now_ns

    def unavailable(self, service: str, now_ns: int) -> None:
        """The halt service had no server when a request was due: nothing was sent."""
        self._failed(self._in_hand("unavailable"), UNAVAILABLE, f"halt service {service} is not available", now_ns)

    def replied(self, success: bool, message: str, now_ns: int) -> PendingHalt | None:
        """The reply to the request in flight; the halt it confirmed (``success``), else None (``refused``)."""
        pending = self._in_hand("replied")
        if pending.sent_ns is None:
            raise RuntimeError("a reply with no request in flight")
        pending.sent_ns = None
        if not success:
            self._failed(pending, REFUSED, f"the halt service refused: {message!r}", now_ns)
            return None
        self.pending = None
        self.confirmed += 1
        return pending

    def timed_out(self, now_ns: int) -> bool:
        """Whether the request in flight has waited past the reply timeout; if so it counts as ``unanswered`` (the
        caller forgets it: a late reply is not taken) and the halt is due again after the retry interval."""
        pending = self.pending
        if pending is None or pending.sent_ns is None or now_ns - pending.sent_ns <= self.reply_timeout_ns:
            return False
        pending.sent_ns = None
        self._failed(pending, UNANSWERED, f"no reply within {self.reply_timeout_ns / 1e9:g} s", now_ns)
        return True

    def error(self) -> str:
        """Why the pending halt is not confirmed (``""``: none is pending, or its first request is in flight)."""
        pending = self.pending
        if pending is None or not pending.failure:
            return ""
        return (f"halt of rollout {pending.decision.rollout_id} not confirmed after {pending.attempts} request(s): "
                f"{pending.failure}")

    def diagnostic_values(self) -> dict[str, str]:
        """The counters and the pending halt, for ``/diagnostics``."""
        pending = self.pending
        values = {"halts_confirmed": str(self.confirmed),
                  "halt_pending": "none" if pending is None else str(pending.decision.rollout_id)}
        return values | {f"halt_{failure}": str(count) for failure, count in self.failures.items()}

    def _in_hand(self, what: str) -> PendingHalt:
        if self.pending is None:
            raise RuntimeError(f"{what}: no halt is pending")
        return self.pending

    def _failed(self, pending: PendingHalt, failure: str, why: str, now_ns: int) -> None:
        self.failures[failure] += 1
        pending.failure = why
        pending.retry_ns = now_ns + self.retry_ns
