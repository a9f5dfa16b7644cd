"""Latency percentiles, message rates and rate-limited logging for the nodes' diagnostics."""
from __future__ import annotations

from collections import deque

import numpy as np


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
