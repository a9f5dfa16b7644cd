"""Who may speak (no DDS): the publisher rule by hand, the fusion's doubt, the supervisor's doubt, resets."""
from __future__ import annotations

import pytest
from helpers.alarm_pairs import fuse_pair
from helpers.states import ALARM, OK, UNKNOWN

from fiper_ros.runtime.alarm import MAX_RESET_TEXT, NO_ROLLOUT, AlarmFuser, AlarmState, reset_refusal
from fiper_ros.runtime.supervision import SupervisorLogic
from fiper_ros.runtime.trusted_publishers import (FOREIGN, SEVERAL, UNIDENTIFIED, UNKNOWN_NODE_NAME,
                                                  UNKNOWN_NODE_NAMESPACE, UNNAMED_GRACE_NS, Expected, Finding,
                                                  Publisher, PublisherWatch, fully_qualified, judge, resolve_node)

S = 1_000_000_000
SCORES = "/fiper/scores/rnd_oe"
RND = "/fiper/rnd_oe_node"
SCORE_TOPIC = Expected(SCORES, frozenset({RND, "/fiper/ace_node"}))


def _pub(node: str, gid: str = "") -> Publisher:
    return Publisher(node, gid or f"gid-{node}")


def test_names_are_fully_qualified_and_unknown_ones_are_empty() -> None:
    assert fully_qualified("/fiper", "rnd_oe_node") == RND
    assert fully_qualified("/", "talker") == "/talker"
    assert fully_qualified("/a/b/", "n") == "/a/b/n"
    assert fully_qualified(UNKNOWN_NODE_NAMESPACE, UNKNOWN_NODE_NAME) == ""
    assert fully_qualified("/fiper", UNKNOWN_NODE_NAME) == ""
    assert resolve_node("rnd_oe_node", "/fiper") == RND
    assert resolve_node("/other/node", "/fiper") == "/other/node"


def test_the_expected_publisher_alone_is_no_finding_and_no_publisher_neither() -> None:
    assert judge(SCORE_TOPIC, [_pub(RND)]) == ()
    assert judge(SCORE_TOPIC, []) == ()  # a missing stream is staleness's business


def test_a_foreign_publisher_is_named() -> None:
    found = judge(SCORE_TOPIC, [_pub(RND), _pub("/intruder")], speaking=2)
    assert found == (Finding(SCORES, FOREIGN, ("/intruder",)),
                     Finding(SCORES, SEVERAL, ("/fiper/rnd_oe_node", "/intruder"), 2))
    assert "/intruder" in str(found[0]) and "does not expect" in str(found[0])
    assert str(found[1]) == f"{SCORES}: 2 publishers where the suite has one: /fiper/rnd_oe_node, /intruder"
    # alone, the foreign one is still foreign (the suite's own may be dead: its scores are not the suite's)
    assert judge(SCORE_TOPIC, [_pub("/intruder")]) == (Finding(SCORES, FOREIGN, ("/intruder",)),)


def test_two_publishers_of_the_same_name_are_a_second_suite_unless_one_is_known_dead() -> None:
    twins = [_pub(RND, "a"), _pub(RND, "b")]
    assert judge(SCORE_TOPIC, twins, speaking=2) == (Finding(SCORES, SEVERAL, (RND, RND), 2),)
    assert judge(SCORE_TOPIC, twins) == (Finding(SCORES, SEVERAL, (RND, RND), 2),)  # liveliness unknown: the graph
    # a killed predecessor's endpoint lingers in the graph with its liveliness lapsed: not a second suite
    assert judge(SCORE_TOPIC, twins, speaking=1) == ()
    assert judge(SCORE_TOPIC, twins, speaking=0) == ()
    # matched before the graph names it: counted all the same
    assert judge(SCORE_TOPIC, [_pub(RND)], speaking=2) == (Finding(SCORES, SEVERAL, (RND,), 2),)


def test_with_an_allow_list_one_publisher_per_allowed_node() -> None:
    both = Expected("/fiper/rollout_events", frozenset({"/sim/bridge_node", "/tools/replay"}))
    assert judge(both, [_pub("/sim/bridge_node"), _pub("/tools/replay")], speaking=2) == ()
    three = [_pub("/sim/bridge_node", "a"), _pub("/sim/bridge_node", "b"), _pub("/tools/replay")]
    assert judge(both, three, speaking=3) == (Finding(both.topic, SEVERAL, ("/sim/bridge_node", "/sim/bridge_node",
                                                                             "/tools/replay"), 3, 2),)
    assert str(judge(both, three, speaking=3)[0]).startswith("/fiper/rollout_events: 3 publishers where the suite "
                                                             "has 2")
    # a foreign publisher makes no room for itself: one allowed node present, so one publisher
    assert judge(both, [_pub("/sim/bridge_node"), _pub("/x")], speaking=2) == (
        Finding(both.topic, FOREIGN, ("/x",)), Finding(both.topic, SEVERAL, ("/sim/bridge_node", "/x"), 2))


def test_without_an_allow_list_any_node_but_only_one() -> None:
    inputs = Expected("/fiper/observation_embedding")
    assert judge(inputs, [_pub("/anyone")]) == ()
    assert judge(inputs, [_pub("/b"), _pub("/a")]) == (Finding(inputs.topic, SEVERAL, ("/a", "/b"), 2),)


def test_an_output_allows_only_its_node_and_no_count() -> None:
    own = Expected("/fiper/alarm", frozenset({"/fiper/fusion_node"}), limited=False)
    assert judge(own, [_pub("/fiper/fusion_node", "a"), _pub("/fiper/fusion_node", "b")]) == ()
    assert judge(own, [_pub("/fiper/fusion_node"), _pub("/test")]) == (Finding(own.topic, FOREIGN, ("/test",)),)


def test_an_unnamed_publisher_counts_and_is_a_finding_only_after_its_grace() -> None:
    unnamed = Publisher("", "x")
    assert judge(SCORE_TOPIC, [unnamed], young={"x"}) == ()
    assert judge(SCORE_TOPIC, [unnamed]) == (Finding(SCORES, UNIDENTIFIED, ("",)),)
    assert "does not name yet" in str(judge(SCORE_TOPIC, [unnamed])[0])
    # young, it still counts beside the suite's own publisher
    assert judge(SCORE_TOPIC, [_pub(RND), unnamed], young={"x"}) == (Finding(SCORES, SEVERAL, ("", RND), 2),)


def test_the_watch_reports_appearances_once_and_times_the_unnamed_grace() -> None:
    watch = PublisherWatch(unnamed_grace_ns=S)
    expected = [SCORE_TOPIC, Expected("/fiper/scores/ace", frozenset({"/fiper/ace_node"}))]
    graph = {SCORES: [_pub(RND)], "/fiper/scores/ace": [_pub("/fiper/ace_node")]}
    assert watch.update(expected, graph, {}, 0) == ([], [])
    graph[SCORES] = [_pub(RND), _pub("/intruder")]
    appeared, gone = watch.update(expected, graph, {SCORES: 2}, S)
    assert [f.kind for f in appeared] == [FOREIGN, SEVERAL] and gone == []
    assert watch.update(expected, graph, {SCORES: 2}, 2 * S) == ([], [])  # still there: not again
    assert watch.seen == 2
    assert watch.doubt([SCORES]).startswith(SCORES) and watch.doubt(["/fiper/scores/ace"]) == ""
    graph[SCORES] = [_pub(RND)]
    appeared, gone = watch.update(expected, graph, {SCORES: 1}, 3 * S)
    assert appeared == [] and len(gone) == 2 and watch.findings == () and watch.doubt([SCORES]) == ""
    # an endpoint whose node stays unnamed: a finding once the grace is over, not before
    graph["/fiper/scores/ace"] = [Publisher("", "z")]
    assert watch.update(expected, graph, {}, 4 * S) == ([], [])
    assert watch.update(expected, graph, {}, 5 * S) == ([], [])
    appeared, _ = watch.update(expected, graph, {}, 5 * S + 1)
    assert appeared == [Finding("/fiper/scores/ace", UNIDENTIFIED, ("",))]


def _pair(fuser: AlarmFuser, step: int, eta: float, now: int = 0, rollout: int = 1) -> AlarmState:
    return fuse_pair(fuser, step, eta, eta, now, rollout=rollout)


def test_the_fusion_never_says_ok_while_the_scores_cannot_be_attributed_and_not_for_the_rest_of_the_rollout() -> None:
    fuser = AlarmFuser("and")
    fuser.start(1, 0)
    assert fuser.doubted(_pair(fuser, 0, 0.1)).state == OK
    fuser.suspect("/fiper/scores/rnd_oe: publisher(s) the suite does not expect: /intruder")
    doubted = fuser.doubted(_pair(fuser, 1, 0.1))
    assert doubted.state == UNKNOWN and "/intruder" in doubted.reason and "cannot be attributed" in doubted.reason
    fuser.suspect("")  # the intruder left: its scores may have hidden an alarm, so the rollout stays doubted
    later = fuser.doubted(_pair(fuser, 2, 0.1))
    assert later.state == UNKNOWN and "could not be attributed" in later.reason and "/intruder" in later.reason
    # doubt never clears an alarm: a certain one is still ALARM, and latched
    alarm = fuser.doubted(_pair(fuser, 3, 2.0))
    assert alarm.state == ALARM and fuser.doubted(_pair(fuser, 4, 0.1)).state == ALARM
    fuser.start(2, 0)  # the next rollout is judged afresh
    assert fuser.doubted(_pair(fuser, 0, 0.1, rollout=2)).state == OK


def test_a_rollout_started_or_reset_in_doubt_is_doubted_from_its_first_score_in_doubt() -> None:
    fuser = AlarmFuser("and")
    fuser.suspect("x")  # no rollout yet: nothing to taint, but a START now is in doubt from its first score
    fuser.start(1, 0)
    assert fuser.doubted(_pair(fuser, 0, 0.1)).state == UNKNOWN
    fuser.suspect("")
    assert fuser.doubted(_pair(fuser, 1, 0.1)).state == UNKNOWN  # step 0's scores may have been foreign
    fuser.reset()  # judged afresh, without doubt now
    assert fuser.doubted(_pair(fuser, 2, 0.1)).state == OK
    fuser.end(1)
    fuser.suspect("y")  # after the END: nothing more to taint
    fuser.suspect("")
    fuser.start(2, 0)
    assert fuser.doubted(_pair(fuser, 0, 0.1, rollout=2)).state == OK


def test_a_rollout_whose_doubt_cleared_before_its_first_score_is_judged() -> None:
    # test_faults, after a respawn of the fusion node (1 in 4 full runs): the new node's graph did not name the
    # ACE node yet when the next rollout started ("1 publisher(s) of a node the graph does not name yet"); the
    # name came before any score, yet the START in doubt tainted the whole rollout: every step UNKNOWN.
    fuser = AlarmFuser("and")
    fuser.suspect("/fiper/scores/ace: 1 publisher(s) of a node the graph does not name yet")
    fuser.start(1, 0)
    fuser.suspect("")  # named: no score was taken in doubt
    assert [fuser.doubted(_pair(fuser, t, 0.1)).state for t in range(3)] == [OK] * 3
    fuser.reset()  # a reset in doubt, cleared before the next score: the same
    fuser.suspect("y")
    fuser.reset()
    fuser.suspect("")
    assert fuser.doubted(_pair(fuser, 3, 0.1)).state == OK


def test_the_supervisor_takes_ok_for_unknown_in_doubt_and_halts_after_its_deadline() -> None:
    logic = SupervisorLogic(deadline_ns=S)
    assert logic.on_state(3, OK, "below thresholds", 0) is None
    assert logic.suspect("/fiper/alarm: 2 publishers where the suite has one", int(0.1 * S)) is None
    assert logic.on_state(3, OK, "below thresholds", int(0.5 * S)) is None  # an OK in doubt: UNKNOWN
    decision = logic.on_clock(int(1.2 * S))  # the UNKNOWN clock runs from the doubt, not from the next message
    assert decision is not None and decision.rollout_id == 3 and "2 publishers" in decision.reason
    # without doubt, the same OKs stop the clock
    calm = SupervisorLogic(deadline_ns=S)
    calm.on_state(3, OK, "", 0)
    calm.suspect("x", int(0.1 * S))
    calm.suspect("", int(0.3 * S))
    assert calm.on_state(3, OK, "", int(0.5 * S)) is None and calm.on_clock(int(1.5 * S)) is None


def test_the_supervisor_halts_on_alarm_whoever_said_it_and_not_while_idle() -> None:
    logic = SupervisorLogic(deadline_ns=S)
    logic.suspect("x", 0)
    for t in range(5):  # the idle heartbeat in doubt: no robot moves, nothing to halt
        assert logic.on_state(NO_ROLLOUT, OK, "no active rollout", t * S // 2) is None
        assert logic.on_clock(t * S // 2 + S // 4) is None
    decision = logic.on_state(4, ALARM, "exceeded", 3 * S)
    assert decision is not None and decision.reason.startswith("ALARM")


@pytest.mark.parametrize(("allowed", "requester", "reason", "refusal"), [
    (True, "operator jane", "gripper cleared by hand", ""),
    (False, "operator jane", "gripper cleared by hand", "switched off"),
    (True, "", "gripper cleared by hand", "requester empty"),
    (True, "operator jane", "  ", "reason empty"),
    (True, "", "", "requester and reason empty"),
    (True, "operator jane", "x" * (MAX_RESET_TEXT + 1), "reason not one printable line"),
    (True, "jane\n[INFO] all fine", "why", "requester not one printable line"),
])
def test_a_reset_names_who_and_why_and_can_be_switched_off(allowed: bool, requester: str, reason: str,
                                                           refusal: str) -> None:
    got = reset_refusal(allowed, requester, reason)
    assert (got == "") if not refusal else (refusal in got), got
    assert reset_refusal(True, "a", "x" * MAX_RESET_TEXT) == ""


# ---- issue #27: survivors of `make mutants FILES=runtime/publishers.py` ----------------------------------------------
def test_a_namespace_keeps_every_character_but_its_trailing_slash() -> None:
    assert fully_qualified("/robotX", "n") == "/robotX/n"
    assert fully_qualified("/X", "n") == "/X/n"


def test_the_watch_counts_speaking_publishers_and_judges_a_topic_absent_from_the_graph() -> None:
    watch = PublisherWatch(unnamed_grace_ns=S)
    twins = {SCORES: [_pub(RND, "a"), _pub(RND, "b")]}  # a killed predecessor's endpoint lingers
    absent = Expected("/fiper/scores/ace", frozenset({"/fiper/ace_node"}))
    assert watch.update([SCORE_TOPIC, absent], twins, {SCORES: 1}, 0) == ([], [])  # one speaks: no second suite
    appeared, _ = watch.update([SCORE_TOPIC, absent], twins, {SCORES: 2}, 1)
    assert appeared == [Finding(SCORES, SEVERAL, (RND, RND), 2)]


def test_the_first_look_at_an_unnamed_publisher_starts_its_grace() -> None:
    watch = PublisherWatch(unnamed_grace_ns=S)
    graph = {SCORES: [Publisher("", "u")]}
    assert watch.update([SCORE_TOPIC], graph, {}, 0) == ([], [])
    appeared, _ = watch.update([SCORE_TOPIC], graph, {}, S + 1)
    assert appeared == [Finding(SCORES, UNIDENTIFIED, ("",))]
    assert str(appeared[0]) == f"{SCORES}: 1 publisher(s) of a node the graph does not name yet"


def test_the_doubt_lists_every_finding_of_the_topics_asked_for() -> None:
    watch = PublisherWatch()
    watch.update([SCORE_TOPIC], {SCORES: [Publisher("", "u"), _pub("/intruder")]}, {SCORES: 2}, 0)
    watch.update([SCORE_TOPIC], {SCORES: [Publisher("", "u"), _pub("/intruder")]}, {SCORES: 2}, UNNAMED_GRACE_NS + 1)
    assert watch.doubt([SCORES]) == (
        f"{SCORES}: 1 publisher(s) of a node the graph does not name yet; "
        f"{SCORES}: publisher(s) the suite does not expect: /intruder; "
        f"{SCORES}: 2 publishers where the suite has one: (a node not named yet), /intruder")
