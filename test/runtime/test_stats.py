"""The policy period a node measures (``PeriodEstimator``): the median time per step of the last intervals."""
from __future__ import annotations

import statistics

from hypothesis import given
from hypothesis import strategies as st

from fiper_ros.runtime.stats import PeriodEstimator

MS = 1_000_000


def test_median_of_the_window_a_gap_counts_as_that_many_periods() -> None:
    period = PeriodEstimator(window=3)
    assert period.period_ns() is None
    period.add(0, 0)
    assert period.period_ns() is None  # one step: no interval yet
    period.add(1, 100 * MS)
    assert period.period_ns() == 100 * MS
    period.add(3, 300 * MS)  # two steps in 200 ms: 100 ms each
    period.add(4, 700 * MS)  # one slow step
    assert period.period_ns() == 100 * MS  # the median of 100, 100, 400
    period.add(5, 1100 * MS)
    period.add(6, 1500 * MS)  # the window now holds 400, 400, 400: the first two fell out
    assert period.period_ns() == 400 * MS


def test_stamps_that_do_not_advance_and_old_steps_say_nothing() -> None:
    period = PeriodEstimator()
    period.add(0, 0)
    period.add(1, 0)  # a policy that leaves its stamps 0
    assert period.period_ns() is None
    period.add(2, 100 * MS)  # from step 1 at 0: 100 ms
    period.add(1, 150 * MS)  # a late, older step
    assert period.period_ns() == 100 * MS


def test_reset_forgets_the_rollout() -> None:
    period = PeriodEstimator()
    period.add(0, 0)
    period.add(1, 50 * MS)
    period.reset()
    assert period.period_ns() is None
    period.add(7, 10 * 100 * MS)
    period.add(8, 11 * 100 * MS)
    assert period.period_ns() == 100 * MS  # not a period from the previous rollout's last step


@given(st.integers(1, 10), st.lists(st.tuples(st.integers(0, 40), st.integers(0, 10**10)), max_size=60),
       st.integers(0, 60))
def test_the_period_is_the_median_of_the_windows_intervals_after_every_step(
        window: int, steps: list[tuple[int, int]], reset_at: int) -> None:
    """Against a reference of the rule: after every step the period is ``int`` of the median of the last
    ``window`` intervals (time / steps between consecutive steps that both advance), None before one."""
    period = PeriodEstimator(window)
    intervals: list[float] = []
    last: tuple[int, int] | None = None
    for i, (step, stamp) in enumerate(steps):
        if i == reset_at:
            period.reset()
            intervals, last = [], None
        period.add(step, stamp)
        if last is not None and step > last[0] and stamp > last[1]:
            intervals.append((stamp - last[1]) / (step - last[0]))
        if last is None or step > last[0]:
            last = (step, stamp)
        expected = int(statistics.median(intervals[-window:])) if intervals else None
        assert period.period_ns() == expected
