"""The fusion node's alarm state machine and the example supervisor's rule (no DDS)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from helpers.alarm_pairs import fuse_pair as _pair
from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.runtime.alarm import NO_ROLLOUT, AlarmFuser, DetectorScore
from fiper_ros.runtime.supervision import SupervisorLogic

S = 1_000_000_000


def test_and_alarms_only_when_both_exceed_and_latches() -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    assert _pair(fuser, 0, 2.0, 0.5, 0).state == OK
    assert _pair(fuser, 1, 0.5, 2.0, 0).state == OK
    state = _pair(fuser, 2, 2.0, 2.0, 0)
    assert state.state == ALARM and state.latched and state.exceeded == (True, True)
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
    # +inf is what a Threshold holds when M is too small for delta; NaN what a Score carries uncalibrated.
    for step, gamma in enumerate((math.inf, math.nan)):
        state = _pair(fuser, step, 0.0, 0.0, 0, gamma=gamma)
        assert state.state == UNKNOWN and "no threshold" in state.reason, gamma


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf])
def test_non_finite_windowed_score_is_unknown_never_ok(bad: float) -> None:
    # The old fuser compared nan > gamma (False) and reported the step as below its threshold: OK.
    for combine in ("and", "or"):
        fuser = AlarmFuser(combine)
        fuser.start(1, 0)
        state = _pair(fuser, 0, bad, 0.0, 0, flags=(False, False))
        assert state.state == UNKNOWN and "rnd_oe" in state.reason and "not finite" in state.reason, combine


def test_the_detectors_full_precision_decision_counts_where_float32_rounds_to_equal() -> None:
    # eta = 1 + 2**-30 > gamma = 1 in float64 (the detector's and the offline oracle's decision), but both
    # round to 1.0f in the Score message: comparing the float32 numbers would report OK.
    eta = float(np.float32(1.0 + 2.0**-30))
    assert eta == 1.0
    fuser = AlarmFuser("or")
    fuser.start(1, 0)
    state = _pair(fuser, 0, eta, 0.0, 0, flags=(True, False))
    assert state.state == ALARM and state.of("rnd_oe")[0] and state.latched


@pytest.mark.parametrize(("obs", "flag"), [(2.0, False), (0.5, True)])
def test_a_score_contradicting_its_own_flag_is_unknown(obs: float, flag: bool) -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    state = _pair(fuser, 0, obs, 0.5, 0, flags=(flag, False))
    assert state.state == UNKNOWN and "contradicting" in state.reason


@pytest.mark.parametrize("combine", ["and", "or"])
def test_a_step_whose_own_input_was_rejected_is_unknown_unless_an_alarm_is_certain(combine: str) -> None:
    fuser = AlarmFuser(combine)
    fuser.start(1, 0)
    # rnd_oe's input of step 0 was rejected (its window leaves it out); ace is complete and below.
    first = fuser.add(DetectorScore("rnd_oe", 1, 0, 0.5, 1.0, 0, False, False, scored=False), 0)
    assert first is None
    state = fuser.add(DetectorScore("ace", 1, 0, 0.5, 1.0, 0, True, False), 0)
    assert state.state == UNKNOWN and "input of this step rejected: rnd_oe" in state.reason
    # the lower bound without the rejected input already exceeds: the alarm is certain (OR), or needs ace (AND)
    fuser.add(DetectorScore("rnd_oe", 1, 1, 2.0, 1.0, 0, False, True, scored=False), 0)
    state = fuser.add(DetectorScore("ace", 1, 1, 0.5, 1.0, 0, True, False), 0)
    assert state.state == (ALARM if combine == "or" else UNKNOWN)


def test_latch_wins_over_everything_until_start_or_reset() -> None:
    fuser = AlarmFuser("and", deadline_ns=S)
    fuser.start(1, 0)
    assert _pair(fuser, 0, 2.0, 2.0, 0).state == ALARM
    after = [
        _pair(fuser, 1, 0.0, 0.0, 0, gamma=math.inf),                    # threshold gone
        _pair(fuser, 2, math.nan, 0.0, 0, flags=(False, False)),         # non-finite score
        _pair(fuser, 3, 2.0, 0.0, 0, flags=(False, False)),              # contradictory score
        _pair(fuser, 4, 0.0, 0.0, 0, complete=(False, False)),           # incomplete windows
        _pair(fuser, 5, 0.0, 0.0, 0),                                    # everything below
    ]
    assert [a.state for a in after] == [ALARM] * 5 and all(a.latched for a in after)
    assert all("latched since step 0" in a.reason for a in after)
    assert fuser.check(10 * S).state == ALARM                          # stale streams
    assert fuser.check(10 * S, frozenset({"ace"})).state == ALARM      # a dead node
    fuser.end(1)
    assert fuser.latched and fuser.last is not None and fuser.last.state == ALARM and fuser.last.rollout_id == 1
    fuser.reset()
    assert not fuser.latched and fuser.last is None
    fuser.start(2, 0)
    assert _pair(fuser, 0, 0.0, 0.0, 0, rollout=2).state == OK


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


def test_a_step_the_end_overtook_is_still_judged_and_the_streams_are_no_longer_expected() -> None:
    fuser = AlarmFuser("and", deadline_ns=S)
    fuser.start(1, 0)
    _pair(fuser, 0, 0.0, 0.0, 0)
    fuser.end(1)
    assert fuser.active_rollout is None and fuser.check(10 * S) is None  # no staleness after the END
    late = _pair(fuser, 1, 2.0, 2.0, 11 * S)
    assert late is not None and late.step == 1 and late.state == ALARM and late.rollout_id == 1
    fuser.start(2, 12 * S)
    assert fuser.add(DetectorScore("rnd_oe", 1, 2, 0.0, 1.0, 0), 12 * S) is None  # rollout 1 is over now


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



def test_a_burst_of_decisions_does_not_shrink_the_silence_deadline() -> None:
    # Seen in the demo under load: a supervisor starved of CPU took the decisions of steps 0-2 in one burst
    # (one clock reading), measured a policy period of 0 from their arrivals, and halted the rollout for one
    # ordinary 0.4 s policy period of silence ("no alarm message for 0.40 s"). The period is the decisions'
    # own stamps' (the policy steps'): 0.4 s, so 2.5 periods = 1 s of silence is tolerated.
    logic = SupervisorLogic(deadline_ns=2 * S, silence_periods=2.5, silence_floor_ns=S // 10)
    logic.on_event(7, started=True)
    burst = 10 * S
    for step in range(3):
        assert logic.on_state(7, OK, "below", burst, step, heartbeat=False, steady_ns=burst,
                              stamp_ns=step * 4 * S // 10) is None
    assert logic.silence_deadline() == S
    assert logic.on_clock(burst + 6 * S // 10, burst + 6 * S // 10) is None  # 0.6 s: more than a period, not 2.5
    decision = logic.on_clock(burst + 11 * S // 10, burst + 11 * S // 10)
    assert decision is not None and decision.reason == "no alarm message for 1.10 s"


def test_a_decision_without_its_stamp_is_refused() -> None:
    with pytest.raises(ValueError, match="needs its stamp"):
        SupervisorLogic(deadline_ns=S).on_state(1, OK, "", 0, 0, heartbeat=False)
