"""Latency percentiles, message rates, policy periods and rate-limited logging for the nodes."""
from __future__ import annotations

from collections import deque

import numpy as np

#: The promise that a dead or hung node is noticed within a few policy periods, in one place: a score stream (the
#: fusion node's ``deadline_periods``) or the alarm stream (the supervisor's ``silence_periods``) silent for this many
#: measured policy periods during a rollout is stale, said at the node's next check (``check_period_s``). So the
#: fusion node repeats its last verdict at most ``floor(DEADLINE_PERIODS)`` times (one per measured period of silence,
#: :meth:`fiper_ros.runtime.alarm.AlarmFuser.heartbeat`) before the UNKNOWN of a stream silent since that verdict,
#: however late its checks run, while the measured period holds (docs/alarm-contract.md).
DEADLINE_PERIODS = 2.5


class LatencyStats:
    """Percentiles of the last ``size`` latencies (milliseconds)."""

    def __init__(self, size: int = 1000) -> None:
        self._values: deque[float] = deque(maxlen=size)

    def add(self, latency_ms: float) -> None:
        """Record one latency."""
        self._values.append(float(latency_ms))

    def percentile(self, q: float) -> float:
        """The ``q``-th percentile (0-100), NaN without data."""
        return float(np.percentile(self._values, q)) if self._values else float("nan")

    def __len__(self) -> int:
        return len(self._values)


class PeriodEstimator:
    """The policy period as seen by a node: the median time per step between consecutive policy steps of one
    rollout, over the last ``window`` intervals. The times are the steps' own stamps (the policy's, which the
    scores and the decisions carry): the fusion node's and the supervisor's arrivals bunch up when they are
    short of CPU, and a burst measured from arrivals gives a period near 0. Stamps that do not advance (a
    policy that leaves them 0) say nothing about the period and are not counted.

    The median keeps one slow step (a GC pause, a busy core) from moving it; a step gap counts as that
    many periods (the time is divided by the step difference). It is computed at the first :meth:`period_ns`
    after an interval arrived and kept until the next one: the fusion node's staleness check asks for it two or
    three times per check at 50 Hz, and a step at 1000 steps/s need not pay for it either (a numpy
    median of the window cost some 25 us per call).
    """

    def __init__(self, window: int = 8) -> None:
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self._intervals: deque[float] = deque(maxlen=window)
        self._last: tuple[int, int] | None = None
        #: The median of :attr:`_intervals`; None until asked for after the latest interval arrived.
        self._median_ns: int | None = None

    def reset(self) -> None:
        """A new rollout: forget the previous one's steps."""
        self._intervals.clear()
        self._last = None
        self._median_ns = None

    def add(self, step: int, now_ns: int) -> None:
        """Policy step ``step`` stamped ``now_ns``."""
        if self._last is not None and step > self._last[0] and now_ns > self._last[1]:
            self._intervals.append((now_ns - self._last[1]) / (step - self._last[0]))
            self._median_ns = None  # computed when next asked for
        if self._last is None or step > self._last[0]:
            self._last = (step, now_ns)

    def period_ns(self) -> int | None:
        """The median period in nanoseconds, or None before two steps arrived."""
        if self._median_ns is None and self._intervals:
            self._median_ns = int(np.median(self._intervals))
        return self._median_ns

    def deadline_ns(self, periods: float, floor_ns: int, fallback_ns: int) -> int:
        """``periods`` measured periods, at least ``floor_ns``; ``fallback_ns`` while the period is unknown or
        ``periods`` is 0 (the one rule of the fusion node's staleness and the supervisor's silence)."""
        period = self.period_ns()
        if periods <= 0 or period is None:
            return fallback_ns
        return max(floor_ns, int(periods * period))


class RateMeter:
    """Messages per second over a sliding window of the last ``window_s`` seconds (node-clock times)."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_ns = int(window_s * 1e9)
        self._stamps: deque[int] = deque()

    def tick(self, now_ns: int) -> None:
        """Record one message received at ``now_ns``."""
        self._stamps.append(now_ns)
        self._trim(now_ns)

    def rate(self, now_ns: int) -> float:
        """Messages per second over the window ending at ``now_ns``."""
        self._trim(now_ns)
        return len(self._stamps) * 1e9 / self.window_ns

    def _trim(self, now_ns: int) -> None:
        while self._stamps and self._stamps[0] <= now_ns - self.window_ns:
            self._stamps.popleft()


class RateLimitedLog:
    """Say a message the first time a key occurs, then at most once per ``period_s`` per key."""

    def __init__(self, period_s: float = 10.0) -> None:
        self.period_ns = int(period_s * 1e9)
        self._last: dict[str, int] = {}
        self.suppressed: dict[str, int] = {}

    def should_log(self, key: str, now_ns: int) -> bool:
        """Whether to log ``key`` now; counts the suppressed occurrences."""
        last = self._last.get(key)
        if last is not None and now_ns - last < self.period_ns:
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            return False
        self._last[key] = now_ns
        return True
