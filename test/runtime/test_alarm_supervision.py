"""The fusion node's alarm state machine and the example supervisor's rule (no DDS)."""
from __future__ import annotations

import math

import pytest

from fiper_ros.runtime.alarm import ALARM, NO_ROLLOUT, OK, UNKNOWN, AlarmFuser, DetectorScore
from fiper_ros.runtime.supervision import SupervisorLogic

S = 1_000_000_000


def _pair(fuser: AlarmFuser, step: int, obs: float, act: float, now: int, *, gamma: float = 1.0,
          complete: tuple[bool, bool] = (True, True), rollout: int = 1):  # noqa: ANN202
    first = fuser.add(DetectorScore("rnd_oe", rollout, step, obs, gamma, now, complete[0]), now)
    assert first is None
    return fuser.add(DetectorScore("ace", rollout, step, act, gamma, now, complete[1]), now)


def test_and_alarms_only_when_both_exceed_and_latches() -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    assert _pair(fuser, 0, 2.0, 0.5, 0).state == OK
    assert _pair(fuser, 1, 0.5, 2.0, 0).state == OK
    state = _pair(fuser, 2, 2.0, 2.0, 0)
    assert state.state == ALARM and state.latched and state.obs_exceeded and state.act_exceeded
    later = _pair(fuser, 3, 0.0, 0.0, 0)
    assert later.state == ALARM and later.latched and "latched since step 2" in later.reason
    fuser.reset()
    assert _pair(fuser, 4, 0.0, 0.0, 0).state == OK


def test_or_alarms_when_either_exceeds() -> None:
    fuser = AlarmFuser("or")
    fuser.start(1, 0)
    assert _pair(fuser, 0, 2.0, 0.5, 0).state == ALARM


def test_threshold_equal_is_not_exceeded() -> None:
    fuser = AlarmFuser("or")
    fuser.start(1, 0)
    assert _pair(fuser, 0, 1.0, 1.0, 0).state == OK


def test_start_clears_latch() -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    assert _pair(fuser, 0, 2.0, 2.0, 0).state == ALARM
    fuser.start(2, 0)
    assert _pair(fuser, 0, 0.0, 0.0, 0, rollout=2).state == OK


def test_missing_threshold_is_unknown_never_ok() -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    state = _pair(fuser, 0, 0.0, 0.0, 0, gamma=math.nan)
    assert state.state == UNKNOWN and "no threshold" in state.reason


@pytest.mark.parametrize(
    ("combine", "obs", "act", "complete", "expected"),
    [
        ("and", 0.5, 0.5, (False, True), OK),        # ace certainly below: AND cannot fire
        ("and", 2.0, 0.5, (True, False), UNKNOWN),   # obs fires, ace window incomplete: unknown
        ("and", 2.0, 2.0, (False, False), ALARM),    # lower bounds above: certain alarm
        ("or", 0.5, 0.5, (False, True), UNKNOWN),    # obs might be above: unknown
        ("or", 2.0, 0.5, (True, False), ALARM),
    ],
)
def test_incomplete_windows_never_yield_an_uncertain_ok(
    combine: str, obs: float, act: float, complete: tuple[bool, bool], expected: str
) -> None:
    fuser = AlarmFuser(combine)
    fuser.start(1, 0)
    assert _pair(fuser, 0, obs, act, 0, complete=complete).state == expected


def test_scores_of_other_rollouts_are_ignored_and_buffer_evicts() -> None:
    fuser = AlarmFuser("and", buffer_size=2)
    fuser.start(1, 0)
    assert fuser.add(DetectorScore("rnd_oe", 7, 0, 1.0, 1.0, 0), 0) is None
    for step in range(4):
        assert fuser.add(DetectorScore("rnd_oe", 1, step, 1.0, 1.0, 0), 0) is None
    assert fuser.evicted == 2
    assert fuser.add(DetectorScore("ace", 1, 3, 0.0, 1.0, 0), 0).step == 3
    assert fuser.unmatched_stale == 1  # step 2 waited in vain


def test_stale_stream_turns_unknown_after_deadline_unless_latched() -> None:
    fuser = AlarmFuser("and", deadline_ns=1 * S)
    fuser.start(1, 0)
    assert fuser.check(S // 2) is None
    _pair(fuser, 0, 0.0, 0.0, S // 2)
    fuser.add(DetectorScore("rnd_oe", 1, 1, 0.0, 1.0, S), S)
    state = fuser.check(2 * S)
    assert state is not None and state.state == UNKNOWN and "ace" in state.reason and "rnd_oe" not in state.reason
    lost = fuser.check(int(1.2 * S), frozenset({"rnd_oe"}))
    assert lost is not None and lost.state == UNKNOWN and "rnd_oe" in lost.reason
    _pair(fuser, 2, 2.0, 2.0, 3 * S)
    assert fuser.check(10 * S).state == ALARM
    fuser.end(1)
    assert fuser.check(20 * S) is None


def test_supervisor_halts_on_alarm_once_per_rollout() -> None:
    logic = SupervisorLogic(deadline_ns=2 * S)
    assert logic.on_state(1, OK, "", 0) is None
    decision = logic.on_state(1, ALARM, "exceeded", S)
    assert decision is not None and decision.rollout_id == 1 and "ALARM" in decision.reason
    assert logic.on_state(1, ALARM, "latched", 2 * S) is None
    assert logic.on_state(2, ALARM, "exceeded", 3 * S) is not None


def test_supervisor_tolerates_short_unknown_but_not_long() -> None:
    logic = SupervisorLogic(deadline_ns=2 * S)
    assert logic.on_state(1, UNKNOWN, "waiting", 0) is None
    assert logic.on_state(1, UNKNOWN, "waiting", S) is None
    assert logic.on_state(1, OK, "", int(1.5 * S)) is None
    assert logic.on_clock(int(1.9 * S)) is None
    assert logic.on_state(1, UNKNOWN, "stale", 2 * S) is None
    assert logic.on_state(1, UNKNOWN, "stale", 3 * S) is None  # heartbeats: not silent
    assert logic.on_state(1, UNKNOWN, "stale", 4 * S) is None
    decision = logic.on_clock(int(4.5 * S))
    assert decision is not None and "UNKNOWN" in decision.reason


def test_supervisor_halts_on_silence() -> None:
    logic = SupervisorLogic(deadline_ns=2 * S)
    assert logic.on_clock(100 * S) is None  # never heard: nothing to supervise yet
    logic.on_state(3, OK, "", 100 * S)
    assert logic.on_clock(101 * S) is None
    decision = logic.on_clock(103 * S)
    assert decision is not None and "no alarm message" in decision.reason
    assert logic.on_clock(104 * S) is None


def test_supervisor_times_unknown_per_rollout_and_not_while_idle() -> None:
    logic = SupervisorLogic(deadline_ns=2 * S)
    # idle: the fusion node's "no active rollout" heartbeats for longer than the deadline halt nothing
    for t in range(6):
        assert logic.on_state(NO_ROLLOUT, UNKNOWN, "no active rollout", t * S) is None
    assert logic.on_clock(int(5.5 * S)) is None
    # a rollout starts: its first scores may take up to the deadline, counted from its own first state
    assert logic.on_state(7, UNKNOWN, "waiting for the first scores", 6 * S) is None
    assert logic.on_clock(int(7.9 * S)) is None
    assert logic.on_state(7, OK, "", 8 * S) is None
    # UNKNOWN carried over from one rollout into the next restarts at the new rollout
    assert logic.on_state(7, UNKNOWN, "stale", 9 * S) is None
    for t in (10.5, 11.5, 12.0):  # heartbeats: not silent
        assert logic.on_state(8, UNKNOWN, "waiting for the first scores", int(t * S)) is None
    assert logic.on_clock(int(12.4 * S)) is None
    decision = logic.on_clock(int(12.6 * S))
    assert decision is not None and decision.rollout_id == 8 and "UNKNOWN for 2.10 s" in decision.reason
