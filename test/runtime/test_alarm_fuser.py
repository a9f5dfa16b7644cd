"""AlarmFuser's states field by field, by hand: every field of every kind of state, the counters, the gap
bookkeeping and the deadline (issue #27: the cases `make mutants` found that no test pinned down)."""
from __future__ import annotations

import math
from dataclasses import asdict

import numpy as np
import pytest
from helpers.alarm_pairs import fuse_pair as _pair
from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.core.errors import ChoiceError
from fiper_ros.core.fusion import alarms_over_rollout
from fiper_ros.runtime.alarm import (NO_ROLLOUT, AlarmFuser, AlarmState, DetectorScore, explanation, ratio_text,
                                     reset_refusal)

S = 1_000_000_000
MS = 1_000_000


def _started(combine: str = "and", **kwargs: float) -> AlarmFuser:
    fuser = AlarmFuser(combine, **kwargs)  # type: ignore[arg-type]
    fuser.start(1, 0)
    return fuser


def _fields(state: AlarmState) -> dict[str, object]:
    """The state as a dict, NaN replaced by the string "nan" (so that == compares it)."""
    def plain(value: object) -> object:
        if isinstance(value, tuple):
            return tuple(plain(v) for v in value)
        return "nan" if isinstance(value, float) and math.isnan(value) else value
    return {k: plain(v) for k, v in asdict(state).items()}


def _state(obs_exceeded: bool = False, act_exceeded: bool = False, eta_obs: object = 0.5, gamma_obs: object = 1.0,
           eta_act: object = 0.25, gamma_act: object = 1.0, **fields: object) -> dict[str, object]:
    """The fields of a state of FIPER's pair (RND-OE, ACE), each detector's numbers given one by one."""
    base = dict(rollout_id=1, step=0, state=OK, latched=False, detectors=("rnd_oe", "ace"),
                exceeded=(obs_exceeded, act_exceeded), windowed=(eta_obs, eta_act), thresholds=(gamma_obs, gamma_act),
                votes=1 if fields.get("combine") == "or" else 2, combine="and", reason="below thresholds", stamp_ns=0)
    return base | fields


# ---- one fused step, every field -------------------------------------------------------------------------------
def test_an_ok_carries_both_detectors_numbers_and_the_later_stamp() -> None:
    state = _pair(_started(), 0, 0.5, 0.25, stamps=(7, 9))
    assert _fields(state) == _state(stamp_ns=9)
    assert _pair(_started("or"), 0, 0.5, 0.25, stamps=(9, 7)).stamp_ns == 9


@pytest.mark.parametrize(("combine", "obs", "act", "reason"), [
    ("and", 2.0, 3.0, "RND-OE 2x threshold since step 4, ACE 3x since step 4: both exceeded (and)"),
    ("or", 0.5, 3.0, "ACE 3x threshold since step 4: one exceeded (or)"),
    ("or", 2.0, 0.5, "RND-OE 2x threshold since step 4: one exceeded (or)")])
def test_an_alarm_explains_which_detectors_exceeded_by_how_much_and_the_combine(combine: str, obs: float,
                                                                                 act: float, reason: str) -> None:
    fuser = _started(combine)
    state = _pair(fuser, 4, obs, act)
    assert _fields(state) == _state(step=4, state=ALARM, latched=True, obs_exceeded=obs > 1, act_exceeded=act > 1,
                                    eta_obs=obs, eta_act=act, combine=combine, reason=reason)
    assert (fuser.latched, fuser.alarm_step) == (True, 4)
    assert _pair(fuser, 5, 0.0, 0.0).reason == f"latched since step 4: {reason}"


@pytest.mark.parametrize(("kwargs", "reason"), [
    (dict(gamma=(math.inf, math.nan)), "no threshold: rnd_oe, ace"),
    (dict(flags=(True, True)), "score not finite or contradicting its exceeded flag: rnd_oe, ace"),
    (dict(scored=(False, False)), "input of this step rejected: rnd_oe, ace"),
])
def test_every_unknown_of_a_step_is_unlatched_and_names_every_detector_concerned(kwargs: dict[str, object],
                                                                                   reason: str) -> None:
    state = _pair(_started(), 0, 0.5, 0.25, **kwargs)  # type: ignore[arg-type]
    assert (state.state, state.latched, state.reason) == (UNKNOWN, False, reason)


def test_an_incomplete_window_names_every_incomplete_detector_and_is_unlatched() -> None:
    state = _pair(_started("or"), 0, 0.5, 0.25, complete=(False, False))
    assert (state.state, state.latched, state.reason) == (UNKNOWN, False, "window holds a missing step: rnd_oe, ace")


# ---- gaps: steps never fused here ------------------------------------------------------------------------------
def test_a_rollout_whose_first_fused_step_is_not_0_is_unknown_about_the_steps_before() -> None:
    fuser = _started()
    state = _pair(fuser, 1, 0.5, 0.25)
    assert (state.state, state.latched) == (UNKNOWN, False)
    assert state.reason == ("not every step of 0..0 was judged (a gap, or this node started after them): an alarm "
                            "there cannot be ruled out")
    fuser.start(2, 0)  # the next rollout starts from step 0 again
    fuser.add(DetectorScore("rnd_oe", 2, 0, 0.5, 1.0, 0, True, False), 0)
    assert fuser.add(DetectorScore("ace", 2, 0, 0.5, 1.0, 0, True, False), 0).state == OK


def test_the_unjudged_range_runs_from_the_first_gap_to_the_latest() -> None:
    fuser = _started()
    _pair(fuser, 0, 0.5, 0.25)
    assert fuser.unjudged is None
    _pair(fuser, 3, 0.5, 0.25)
    assert fuser.unjudged == (1, 2)
    state = _pair(fuser, 6, 0.5, 0.25)
    assert fuser.unjudged == (1, 5) and "not every step of 1..5 was judged" in state.reason
    fuser.reset()  # judged afresh: the gaps before the reset no longer count
    assert fuser.unjudged is None and _pair(fuser, 7, 0.5, 0.25).state == OK


def test_steps_left_waiting_for_their_partner_are_counted_one_by_one_and_across_starts() -> None:
    fuser = _started()
    for step in (0, 1):
        fuser.add(DetectorScore("rnd_oe", 1, step, 0.5, 1.0, 0), 0)
    _pair(fuser, 2, 0.5, 0.25)
    assert (fuser.unmatched_stale, fuser.matched) == (2, 1)
    fuser.add(DetectorScore("ace", 1, 3, 0.5, 1.0, 0), 0)
    fuser.start(2, 0)  # step 3 of rollout 1 never got its partner
    assert fuser.unmatched_stale == 3
    fuser.add(DetectorScore("rnd_oe", 2, 0, 0.5, 1.0, 0), 0)
    fuser.start(3, 0)
    assert fuser.unmatched_stale == 4


# ---- states about no step: staleness, loss, heartbeats ---------------------------------------------------------
def test_a_stale_stream_before_any_step_is_a_complete_unknown_about_no_step() -> None:
    fuser = _started(deadline_ns=S)
    state = fuser.check(2 * S)
    assert state is not None
    assert _fields(state) == _state(step=0, state=UNKNOWN, eta_obs="nan", gamma_obs="nan", eta_act="nan",
                                    gamma_act="nan", reason="stream(s) ace, rnd_oe missing or older than 1 s",
                                    stamp_ns=2 * S)


def test_a_stale_stream_after_a_step_keeps_its_numbers_and_says_the_deadline() -> None:
    fuser = _started(deadline_ns=1_500_000_000)
    _pair(fuser, 3, 0.5, 0.25, stamps=(5, 5))
    state = fuser.check(2 * S)
    assert state is not None
    assert _fields(state) == _state(step=3, state=UNKNOWN, reason="stream(s) ace, rnd_oe missing or older than 1.5 s",
                                    stamp_ns=2 * S)


def test_a_latched_alarm_stays_alarm_and_latched_when_a_stream_goes_stale() -> None:
    fuser = _started(deadline_ns=S)
    _pair(fuser, 0, 2.0, 2.0)
    state = fuser.check(2 * S)
    assert state is not None and (state.state, state.latched, state.step, state.stamp_ns) == (ALARM, True, 0, 2 * S)


def test_a_lost_stream_counts_only_while_a_rollout_runs_and_only_if_declared() -> None:
    fuser = AlarmFuser("and", deadline_ns=S)
    assert fuser.check(0, frozenset({"ace"})) is None  # no rollout
    fuser.start(1, 0)
    lost = fuser.check(1, frozenset({"ace", "stac"}))
    assert lost is not None and lost.reason == "stream(s) ace missing or older than 1 s"
    assert lost.rollout_id == 1 and lost.latched is False
    fuser.end(1)
    assert fuser.check(2, frozenset({"ace"})) is None


def test_the_heartbeat_state_is_the_last_step_while_it_runs_or_latches_else_a_state_about_no_step() -> None:
    fuser = AlarmFuser("or")
    idle = fuser.current(5)
    assert _fields(idle) == _state(rollout_id=NO_ROLLOUT, state=UNKNOWN, eta_obs="nan", gamma_obs="nan",
                                   eta_act="nan", gamma_act="nan", combine="or", reason="no active rollout",
                                   stamp_ns=5)
    fuser.start(1, 0)
    waiting = fuser.current(6)
    assert (waiting.rollout_id, waiting.state, waiting.reason, waiting.stamp_ns) == \
        (1, UNKNOWN, "waiting for the first scores of the rollout", 6)
    step = _pair(fuser, 0, 0.5, 0.25)
    assert fuser.current(7) is step
    fuser.end(1)
    assert fuser.current(8).reason == "no active rollout"  # an OK of an ended rollout is not repeated
    fuser.start(2, 0)
    fuser.add(DetectorScore("rnd_oe", 2, 0, 2.0, 1.0, 0, True, True), 0)
    alarm = fuser.add(DetectorScore("ace", 2, 0, 0.5, 1.0, 0, True, False), 0)
    fuser.end(2)
    assert fuser.current(9) is alarm and alarm.state == ALARM  # a latched ALARM stays the state after its END
    fuser.reset()
    after = fuser.current(10)
    assert (after.rollout_id, after.state, after.latched) == (NO_ROLLOUT, UNKNOWN, False)


# ---- construction, lifecycle, doubt ----------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs", [dict(deadline_ns=0), dict(deadline_ns=-1), dict(deadline_periods=-0.1),
                                    dict(deadline_floor_ns=-1)])
def test_each_bad_deadline_setting_is_refused_on_its_own(kwargs: dict[str, float]) -> None:
    with pytest.raises(ValueError, match="^deadline_ns must be > 0, deadline_periods and deadline_floor_ns >= 0$"):
        AlarmFuser("and", **kwargs)  # type: ignore[arg-type]


def test_the_smallest_settings_are_accepted_and_a_bad_combine_is_named() -> None:
    fuser = AlarmFuser("and", deadline_ns=1, deadline_periods=0.0, deadline_floor_ns=0)
    assert fuser.deadline() == 1
    with pytest.raises(ChoiceError, match="unknown combine 'xor'; expected one of and, or, max, kth:K"):
        AlarmFuser("xor")
    with pytest.raises(ValueError, match=r"detector 'stac' is not fused here \(detectors rnd_oe, ace\)"):
        _started().add(DetectorScore("stac", 1, 0, 0.0, 1.0, 0), 0)


def test_a_fresh_fuser_has_no_rollout_no_latch_and_no_doubt() -> None:
    fuser = AlarmFuser()
    assert (fuser.rollout_id, fuser.active_rollout, fuser.latched, fuser.alarm_step, fuser.last, fuser.unjudged,
            fuser.suspicion, fuser.tainted) == (None, None, False, None, None, None, "", "")
    assert fuser.add(DetectorScore("rnd_oe", 1, 0, 0.0, 1.0, 0), 0) is None  # no START yet: nothing is matched
    assert fuser.check(10 * S) is None


def test_by_default_the_deadline_is_fixed_whatever_the_measured_period() -> None:
    fuser = _started()  # deadline_ns 1 s, deadline_periods 0
    for step in range(5):
        _pair(fuser, step, 0.5, 0.25, now=step * 100 * MS)
    assert fuser.period.period_ns() == 100 * MS and fuser.deadline() == S
    assert fuser.check(400 * MS + S // 2) is None


def test_the_adaptive_deadline_is_periods_times_the_period_but_at_least_the_floor() -> None:
    fuser = _started(deadline_periods=3.0, deadline_floor_ns=250 * MS)
    assert fuser.deadline() == S  # period unknown yet
    for step in range(5):
        _pair(fuser, step, 0.5, 0.25, now=step * 100 * MS)
    assert fuser.deadline() == 300 * MS
    fuser.deadline_periods = 2.0
    assert fuser.deadline() == 250 * MS  # 200 ms measured, the floor wins
    state = fuser.check(400 * MS + 260 * MS)
    assert state is not None and state.reason == "stream(s) ace, rnd_oe missing or older than 0.25 s"


def test_a_burst_of_scores_does_not_shrink_the_stale_deadline() -> None:
    # The supervisor's burst (test_alarm_supervision) in the fusion node: a node short of CPU takes the scores of
    # steps 0-3 in one burst (one clock reading). Measured from arrivals, the period was 0 and the deadline its
    # 0.1 s floor: an ordinary 10 Hz step then read as a stale stream. The period is the scores' stamps' (the
    # policy steps'): 100 ms, so 2.5 periods = 250 ms of quiet are tolerated.
    fuser = _started(deadline_periods=2.5, deadline_floor_ns=100 * MS)
    burst = 5 * S
    for step in range(4):
        _pair(fuser, step, 0.5, 0.25, now=burst, stamps=(step * 100 * MS, step * 100 * MS))
    assert fuser.period.period_ns() == 100 * MS and fuser.deadline() == 250 * MS
    assert fuser.check(burst + 200 * MS) is None
    state = fuser.check(burst + 260 * MS)
    assert state is not None and state.reason == "stream(s) ace, rnd_oe missing or older than 0.25 s"


def test_stamps_that_do_not_advance_say_nothing_about_the_period() -> None:
    # A policy that leaves its stamps 0: no period is measured, the fixed deadline_ns holds (not the floor).
    fuser = _started(deadline_periods=2.5, deadline_floor_ns=100 * MS)
    for step in range(4):
        _pair(fuser, step, 0.5, 0.25, now=step * 100 * MS, stamps=(0, 0))
    assert fuser.period.period_ns() is None and fuser.deadline() == S


def test_a_start_and_a_reset_clear_the_last_state_and_the_latch_field_by_field() -> None:
    fuser = _started()
    _pair(fuser, 0, 2.0, 2.0)
    fuser.reset()
    assert (fuser.latched, fuser.alarm_step, fuser.last, fuser.tainted) == (False, None, None, "")
    _pair(fuser, 1, 2.0, 2.0)
    fuser.start(2, 0)
    assert (fuser.latched, fuser.alarm_step, fuser.last, fuser.active_rollout) == (False, None, None, 2)
    state = fuser.check(10 * S)
    assert state is not None and state.latched is False and state.state == UNKNOWN


def test_doubt_while_no_rollout_runs_taints_nothing_and_its_reasons_are_exact() -> None:
    fuser = AlarmFuser("and")
    fuser.suspect("x")  # idle
    assert fuser.tainted == ""
    fuser.start(1, 0)  # started in doubt: tainted from the first score it takes in doubt
    assert fuser.tainted == ""
    doubted = fuser.doubted(_pair(fuser, 0, 0.5, 0.25))
    assert doubted.reason == "scores cannot be attributed to the suite: x" and fuser.tainted == "x"
    fuser.suspect("")
    later = fuser.doubted(_pair(fuser, 1, 0.5, 0.25))
    assert later.reason == "scores of this rollout could not be attributed to the suite (x): an alarm cannot be ruled out"
    fuser.end(1)
    fuser.reset()
    fuser.suspect("y")  # after the END: nothing runs, nothing to taint
    assert fuser.tainted == ""


def test_reset_refusals_are_exact() -> None:
    assert reset_refusal(False, "a", "b") == ("resets are switched off (allow_reset false): only the next rollout's "
                                              "START clears the latch")
    assert reset_refusal(True, "\n", "\t") == "a reset names who asks and why: requester and reason empty"
    assert reset_refusal(True, "a\nb", "c\td") == \
        "requester and reason not one printable line of at most 200 characters"


def test_by_default_64_steps_wait_for_their_partner_and_the_oldest_is_evicted_first() -> None:
    fuser = _started()
    for step in range(65):
        fuser.add(DetectorScore("rnd_oe", 1, step, 0.5, 1.0, 0), 0)
    assert fuser.evicted == 1
    assert fuser.add(DetectorScore("ace", 1, 1, 0.5, 1.0, 0), 0) is not None  # step 1 waited: step 0 went
    assert (fuser.evicted, fuser.unmatched_stale) == (1, 0)


@pytest.mark.parametrize("combine", ["and", "or"])
def test_the_fusers_latch_equals_the_offline_running_or_of_eq_7(combine: str) -> None:
    # the live latch (this fuser) against the offline oracle's (core.fusion.alarms_over_rollout, then a running OR)
    rng = np.random.default_rng(0)
    seen_alarm = seen_quiet = 0
    for rollout in range(1, 201):
        length = int(rng.integers(1, 30))
        eta_o, eta_a = rng.random(length), rng.random(length)
        gamma_o, gamma_a = np.full(length, 0.8), rng.uniform(0.7, 0.95, length)
        alarms, first = alarms_over_rollout(eta_o, gamma_o, eta_a, gamma_a, combine)
        fuser = AlarmFuser(combine)
        fuser.start(rollout, 0)
        states = []
        for t in range(length):
            fuser.add(DetectorScore("rnd_oe", rollout, t, eta_o[t], gamma_o[t], 0, True, bool(eta_o[t] > gamma_o[t])), 0)
            states.append(fuser.add(DetectorScore("ace", rollout, t, eta_a[t], gamma_a[t], 0, True,
                                                  bool(eta_a[t] > gamma_a[t])), 0))
        assert [s.state for s in states] == [ALARM if a else OK for a in np.logical_or.accumulate(alarms)]
        assert fuser.alarm_step == first
        seen_alarm += first is not None
        seen_quiet += first is None
    assert seen_alarm and seen_quiet  # both outcomes exercised


# ---- the alarm's one line: which score, how far over its threshold, since which step (issue #22) ---------------
@pytest.mark.parametrize(("windowed", "threshold", "text"), [
    (1.9, 1.0, "1.9x"), (2.1, 2.0, "1.05x"), (1.0, 1.0, "1x"), (24.69, 2.0, "12.3x"), (99.96, 1.0, "100x"),
    (999.4, 1.0, "999x"), (999.5, 1.0, "1000x"), (2469.2, 2.0, "1235x"),
    (0.5, 0.0, "0.5 > threshold 0"), (0.5, -0.25, "0.5 > threshold -0.25"), (0.5, math.inf, "0.5 > threshold inf"),
    (math.inf, 1.0, "inf > threshold 1"), (math.nan, 1.0, "nan > threshold 1"),
    (0.5, math.nan, "0.5 > threshold nan"),
])
def test_a_ratio_to_the_threshold_reads_in_three_digits_and_both_numbers_where_a_ratio_says_nothing(
        windowed: float, threshold: float, text: str) -> None:
    assert ratio_text(windowed, threshold) == text


def test_the_explanation_names_each_exceeded_score_once_and_who_exceeded() -> None:
    both = [("rnd_oe", 1.9, 1.0, 10), ("ace", 2.1, 2.0, 25)]
    assert explanation(both, 2, "(and)") == \
        "RND-OE 1.9x threshold since step 10, ACE 1.05x since step 25: both exceeded (and)"
    assert explanation(both[1:], 2, "(or)") == "ACE 1.05x threshold since step 25: one exceeded (or)"
    assert explanation(both[:1], 1, "(alone)") == "RND-OE 1.9x threshold since step 10: exceeded (alone)"
    zero = [("rnd_oe", 0.5, 0.0, 3), ("ace", 2.1, 2.0, 4)]  # the word "threshold" once, where the first ratio is
    assert explanation(zero, 2, "(or)") == \
        "RND-OE 0.5 > threshold 0 since step 3, ACE 1.05x since step 4: both exceeded (or)"


def test_and_says_since_when_each_score_has_exceeded_without_a_break() -> None:
    fuser = _started()
    assert _pair(fuser, 0, 1.5, 0.5).state == OK
    assert _pair(fuser, 1, 0.5, 0.5).state == OK  # RND-OE's run breaks here
    for step in (2, 3):
        assert _pair(fuser, step, 1.5, 0.5).state == OK
    assert fuser.exceeding_since == {"rnd_oe": 2}
    state = _pair(fuser, 4, 1.9, 1.05)
    assert state.state == ALARM
    assert state.reason == "RND-OE 1.9x threshold since step 2, ACE 1.05x since step 4: both exceeded (and)"
    assert _pair(fuser, 5, 0.0, 0.0, gamma=(math.inf, 1.0)).reason == f"latched since step 4: {state.reason}"
    fuser.reset()  # judged afresh: runs before the reset no longer count
    assert fuser.exceeding_since == {} and fuser.explained == ""
    assert _pair(fuser, 6, 3.0, 3.0).reason == \
        "RND-OE 3x threshold since step 6, ACE 3x since step 6: both exceeded (and)"
    fuser.start(2, 0)
    assert fuser.exceeding_since == {} and fuser.explained == ""


def test_or_names_the_one_that_exceeded_and_since_when_and_both_when_both_do() -> None:
    fuser = _started("or")
    assert _pair(fuser, 0, 0.5, 1.2).reason == "ACE 1.2x threshold since step 0: one exceeded (or)"
    other = _started("or")
    _pair(other, 0, 0.5, 0.5)
    _pair(other, 1, 0.5, 0.5, gamma=(1.0, 1.0))
    assert _pair(other, 2, 2.5, 4.0, gamma=(1.0, 2.0)).reason == \
        "RND-OE 2.5x threshold since step 2, ACE 2x since step 2: both exceeded (or)"


def test_an_undecided_step_and_a_step_never_judged_break_a_run() -> None:
    fuser = _started()
    _pair(fuser, 0, 1.5, 0.5)
    assert _pair(fuser, 1, 1.5, 0.5, flags=(False, False)).state == UNKNOWN  # contradicts its flag: undecided
    assert fuser.exceeding_since == {}
    _pair(fuser, 2, 1.5, 0.5)
    assert fuser.exceeding_since == {"rnd_oe": 2}
    state = _pair(fuser, 5, 1.5, 1.5)  # steps 3 and 4 never fused here
    assert state.state == ALARM and state.reason == \
        "RND-OE 1.5x threshold since step 5, ACE 1.5x since step 5: both exceeded (and)"


def test_a_zero_threshold_is_said_with_both_numbers() -> None:
    state = _pair(_started("or"), 0, 0.5, 0.25, gamma=(0.0, 1.0))
    assert (state.state, state.reason) == (ALARM, "RND-OE 0.5 > threshold 0 since step 0: one exceeded (or)")
