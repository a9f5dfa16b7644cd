"""The heartbeat rule (:meth:`AlarmFuser.heartbeat`): what the fusion node's periodic check publishes, by hand (no
DDS). Silence is repeated after ``heartbeat_s`` or one measured policy period; a stale stream, a lost one and doubt
are said at once, once; a latched ALARM stays ALARM."""
from __future__ import annotations

from helpers.alarm_pairs import fuse_pair
from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.runtime.alarm import AlarmFuser, AlarmState

MS = 1_000_000
HEARTBEAT = 500 * MS


def said(state: AlarmState) -> tuple[int, str, str]:
    """What the node remembers of its last publication."""
    return state.rollout_id, state.state, state.reason


def running(steps: int, period: int = 100 * MS) -> AlarmFuser:
    """A fuser with a rollout whose ``steps`` steps (stamped ``period`` apart) were fused below the thresholds."""
    fuser = AlarmFuser("and", deadline_ns=1000 * MS, deadline_periods=2.5, deadline_floor_ns=100 * MS)
    fuser.start(1, 0)
    for step in range(steps):
        assert fuse_pair(fuser, step, 0.5, 0.5, step * period, stamps=(step * period,) * 2).state == OK
    return fuser


def test_without_a_rollout_the_unknown_is_repeated_after_heartbeat_s_and_not_before() -> None:
    fuser = AlarmFuser("and")
    assert fuser.heartbeat(499 * MS, HEARTBEAT, 0, None) is None
    state = fuser.heartbeat(500 * MS, HEARTBEAT, 0, None)
    assert state is not None and state.state == UNKNOWN and state.reason == "no active rollout"
    assert fuser.repeat_ns(HEARTBEAT) == HEARTBEAT  # no period without a rollout


def test_during_a_rollout_silence_is_repeated_after_one_measured_period() -> None:
    fuser = running(6)  # steps 100 ms apart: the period is 100 ms, shorter than heartbeat_s
    assert fuser.repeat_ns(HEARTBEAT) == 100 * MS
    last = fuser.last
    assert last is not None
    assert fuser.heartbeat(599 * MS, HEARTBEAT, 500 * MS, said(last)) is None  # 99 ms of silence
    repeated = fuser.heartbeat(600 * MS, HEARTBEAT, 500 * MS, said(last))
    assert repeated == last  # the latest fused state itself, its step and stamp


def test_a_stale_stream_is_said_at_once_and_then_only_after_silence() -> None:
    fuser = running(6)
    last = fuser.last
    assert last is not None
    deadline = fuser.deadline()  # 2.5 periods = 250 ms after the last score (500 ms)
    assert deadline == 250 * MS
    now = 500 * MS + deadline + 1
    stale = fuser.heartbeat(now, 10 * HEARTBEAT, now, said(last))  # published just now: still said, it changed
    assert stale is not None and stale.state == UNKNOWN and stale.reason == "stream(s) ace, rnd_oe missing or older than 0.25 s"
    assert fuser.heartbeat(now + MS, 10 * HEARTBEAT, now, said(stale)) is None  # said already, not silent long
    assert fuser.heartbeat(now + 100 * MS, 10 * HEARTBEAT, now, said(stale)) == \
        fuser.check(now + 100 * MS)  # after a period of silence: repeated (with the new stamp)


def test_a_lost_stream_is_said_at_once() -> None:
    fuser = running(3)
    last = fuser.last
    assert last is not None
    lost = fuser.heartbeat(250 * MS, HEARTBEAT, 250 * MS, said(last), frozenset({"ace"}))
    assert lost is not None and lost.state == UNKNOWN and lost.reason.startswith("stream(s) ace missing")


def test_doubt_turns_the_repeated_ok_into_unknown_at_once() -> None:
    fuser = running(3)
    last = fuser.last
    assert last is not None
    fuser.suspect("an unexpected publisher on /fiper/scores/ace")
    doubted = fuser.heartbeat(210 * MS, HEARTBEAT, 210 * MS, said(last))
    assert doubted is not None and doubted.state == UNKNOWN
    assert doubted.reason == "scores cannot be attributed to the suite: an unexpected publisher on /fiper/scores/ace"


def test_a_latched_alarm_stays_alarm_when_its_streams_go_stale() -> None:
    fuser = running(3)
    alarm = fuse_pair(fuser, 3, 2.0, 2.0, 300 * MS, stamps=(300 * MS,) * 2)
    assert alarm.state == ALARM
    now = 300 * MS + fuser.deadline() + 1
    stale = fuser.heartbeat(now, HEARTBEAT, 300 * MS, said(alarm))
    assert stale is not None and stale.state == ALARM and stale.latched and "missing or older" in stale.reason
