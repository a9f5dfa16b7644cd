"""The fusion state machine with RND-OE alone (an observation-only calibration, issue #19), by hand: the alarm
is RND-OE's exceedance whatever the combine, every guarantee of the pair holds (latch, UNKNOWN on non-finite,
rejected or incomplete input, unjudged steps), and only the rnd_oe stream is waited for, aged and watched."""
from __future__ import annotations

import math

import pytest
from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.core.errors import ChoiceError
from fiper_ros.runtime.alarm import AlarmFuser, AlarmState, DetectorScore

S = 1_000_000_000
ALONE = "(rnd_oe alone: combine does not apply)"


def _fuser(combine: str = "and", **kwargs: int) -> AlarmFuser:
    fuser = AlarmFuser(combine, detectors=("rnd_oe",), **kwargs)
    fuser.start(1, 0)
    return fuser


def _score(fuser: AlarmFuser, step: int, eta: float, now: int = 0, *, gamma: float = 1.0, complete: bool = True,
           flag: bool | None = None, scored: bool = True) -> AlarmState | None:
    exceeded = eta > gamma if flag is None else flag
    return fuser.add(DetectorScore("rnd_oe", 1, step, eta, gamma, now, complete, exceeded, scored), now)


@pytest.mark.parametrize("combine", ["and", "or"])
def test_the_alarm_is_rnd_oes_exceedance_and_latches_whatever_the_combine(combine: str) -> None:
    fuser = _fuser(combine)
    ok = _score(fuser, 0, 0.5)
    assert ok is not None and ok.state == OK and ok.reason == f"below threshold {ALONE}"
    assert (ok.combine, ok.detectors, ok.votes) == ("", ("rnd_oe",), 1)
    assert ok.of("rnd_oe") == (False, 0.5, 1.0)
    assert ok.of("ace")[0] is False and all(math.isnan(v) for v in ok.of("ace")[1:])  # not declared
    assert _score(fuser, 1, 1.0).state == OK  # equal is not exceeded (strict >)
    alarm = _score(fuser, 2, 2.0)
    assert alarm.state == ALARM and alarm.latched and alarm.exceeded == (True,) and alarm.combine == ""
    assert alarm.reason == f"RND-OE 2x threshold since step 2: exceeded {ALONE}"
    later = _score(fuser, 3, 0.0)
    assert later.state == ALARM and later.reason == f"latched since step 2: {alarm.reason}"
    fuser.reset()
    assert _score(fuser, 4, 0.0).state == OK


def test_the_pair_keeps_its_combine_and_reasons() -> None:
    fuser = AlarmFuser("or")
    fuser.start(1, 0)
    assert fuser.detectors == ("rnd_oe", "ace") and fuser.combined == "or"
    assert fuser.add(DetectorScore("rnd_oe", 1, 0, 2.0, 1.0, 0, True, True), 0) is None  # waits for ace
    state = fuser.add(DetectorScore("ace", 1, 0, 0.0, 1.0, 0, True, False), 0)
    assert (state.state, state.combine) == (ALARM, "or")
    assert state.reason == "RND-OE 2x threshold since step 0: one exceeded (or)"


@pytest.mark.parametrize("gamma", [math.inf, math.nan])
def test_no_threshold_is_unknown(gamma: float) -> None:
    state = _score(_fuser(), 0, 0.0, gamma=gamma, flag=False)
    assert state.state == UNKNOWN and state.reason == "no threshold: rnd_oe"


@pytest.mark.parametrize(("eta", "flag"), [(math.nan, False), (math.inf, True), (2.0, False), (0.5, True)])
def test_a_non_finite_or_self_contradicting_score_is_unknown(eta: float, flag: bool) -> None:
    state = _score(_fuser(), 0, eta, flag=flag)
    assert state.state == UNKNOWN and "not finite or contradicting" in state.reason


def test_an_incomplete_window_is_unknown_unless_it_already_exceeds() -> None:
    fuser = _fuser()
    state = _score(fuser, 0, 0.5, complete=False)
    assert state.state == UNKNOWN and state.reason == "window holds a missing step: rnd_oe"
    assert _score(fuser, 1, 2.0, complete=False).state == ALARM  # a lower bound above the threshold is certain


def test_a_rejected_input_is_unknown_unless_its_lower_bound_already_exceeds() -> None:
    fuser = _fuser()
    state = _score(fuser, 0, 0.5, complete=False, scored=False)
    assert state.state == UNKNOWN and state.reason == "input of this step rejected: rnd_oe"
    assert _score(fuser, 1, 2.0, complete=False, scored=False).state == ALARM


def test_a_step_never_judged_keeps_the_rollout_from_ok() -> None:
    fuser = _fuser()
    assert _score(fuser, 0, 0.5).state == OK
    gap = _score(fuser, 3, 0.5)  # steps 1 and 2 never arrived: the latch may have fired there
    assert gap.state == UNKNOWN and gap.reason.startswith("not every step of 1..2 was judged")
    assert _score(fuser, 4, 2.0).state == ALARM


def test_only_the_rnd_oe_stream_is_aged_and_watched() -> None:
    fuser = _fuser(deadline_ns=S)
    _score(fuser, 0, 0.5, now=0)
    assert fuser.check(S) is None  # no ACE score ever came: nothing missing
    assert fuser.check(S, lost=frozenset({"ace"})) is None  # a lost ace publisher is not this suite's stream
    lost = fuser.check(S, lost=frozenset({"rnd_oe", "ace"}))
    assert lost.state == UNKNOWN and lost.reason.startswith("stream(s) rnd_oe missing") and lost.combine == ""
    stale = fuser.check(S + 1)
    assert stale.state == UNKNOWN and stale.reason.startswith("stream(s) rnd_oe missing or older than 1 s")
    assert fuser.stale_streams(S + 1) == ["rnd_oe"]


def test_the_pair_reports_a_missing_ace_stream() -> None:
    fuser = AlarmFuser("and", deadline_ns=S)  # the counterpart of the test above, so it can fail
    fuser.start(1, 0)
    fuser.add(DetectorScore("rnd_oe", 1, 0, 0.5, 1.0, S // 2, True, False), S // 2)
    assert fuser.check(S // 2, lost=frozenset({"ace"})).reason.startswith("stream(s) ace missing")
    assert fuser.stale_streams(S + 1) == ["ace"]


def test_an_ace_score_is_refused_and_no_state_waits_for_one() -> None:
    fuser = _fuser()
    with pytest.raises(ValueError, match="not fused here"):
        fuser.add(DetectorScore("ace", 1, 0, 0.5, 1.0, 0, True, False), 0)
    assert all(_score(fuser, step, 0.5) is not None for step in range(5))  # every score is a verdict at once
    assert fuser.matched == 5 and fuser.evicted == 0


@pytest.mark.parametrize(("detectors", "error", "reason"), [
    ((), ChoiceError, "declare each detector once, at least one, got [(]none[)]"),
    (("rnd_oe", "rnd_oe"), ChoiceError, "declare each detector once, at least one, got rnd_oe,rnd_oe"),
    (("rnd_oe", "nope"), ChoiceError, "unknown detector 'nope'")])
def test_an_unsupported_detector_set_is_refused(detectors: tuple[str, ...], error: type[Exception], reason: str) -> None:
    with pytest.raises(error, match=reason):
        AlarmFuser("and", detectors=detectors)
