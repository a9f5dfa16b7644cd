"""The demo's per-rollout record, its verdicts, its problems and its figure, for FIPER's pair and for an
observation-only calibration (RND-OE alone); the demo's launch config and progress line."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib.pyplot as plt
import pytest

from fiper_msgs.msg import FailureAlarm
from fiper_ros.client.driver import alarm_line
from fiper_ros.client.figure import plot_trace, trace_figure
from fiper_ros.client.suite_process import suite_topics
from fiper_ros.client.trace import EARLY_MESSAGES, RolloutEvents, RolloutTrace
from fiper_ros.commands.demo import (SUPERVISOR, VIEW, demo_config, managed_nodes, plain_nodes, problems_of,
                                     recorded_every_step)
from fiper_ros.core.detectors import ACE, DETECTORS, OBSERVATION_ONLY, RND_OE
from fiper_ros.interface.topics import ACTIONS_TOPIC, EMBEDDING_TOPIC, SCORE_ACE_TOPIC, SCORE_RND_OE_TOPIC, TOPICS

DEMO_YAML = Path(__file__).resolve().parents[2] / "fiper_ros" / "launch" / "demo.launch.yaml"


def scored(steps: int, alarm: int | None = None, outcome: str = "failure",
           detectors: tuple[str, ...] = DETECTORS, combine: str = "and") -> RolloutTrace:
    trace = RolloutTrace("harmful OOD", "box_pos", 7, rollout_id=(1 << 32) | 7, detectors=detectors, combine=combine)
    for step in range(steps):
        trace.scores[RND_OE].add(step, 0.5 * step, 2.0, 0.5 * step > 2.0)
        if ACE in detectors:
            trace.scores[ACE].add(step, 10.0 - step, 6.0 + step, False)
    trace.steps_started = steps
    trace.alarm_step = alarm
    trace.outcome = outcome
    return trace


def test_series_are_sorted_by_step_and_a_repeated_step_replaces_its_value() -> None:
    trace = RolloutTrace("in-distribution", "id", 1)
    series = trace.scores[RND_OE]
    series.add(2, 3.0, 1.0, True)
    series.add(0, 1.0, 1.0, False)
    series.add(2, 4.0, 1.5, True)
    steps, windowed, threshold = series.arrays()
    assert steps.tolist() == [0, 2]
    assert windowed.tolist() == [1.0, 4.0]
    assert threshold.tolist() == [1.0, 1.5]


@pytest.mark.parametrize(("alarm", "outcome", "verdict"), [
    (None, "success", "no alarm, task succeeded"),
    (None, "failure", "no alarm: a missed failure"),
    (4, "success", "alarm at step 4, yet the task succeeded: a false alarm"),
    (4, "failure", "alarm at step 4: the supervisor halted the robot"),
])
def test_verdict_names_what_fiper_did(alarm: int | None, outcome: str, verdict: str) -> None:
    trace = scored(6, alarm, outcome)
    assert trace.verdict() == verdict


def test_a_fully_scored_rollout_has_no_problems_and_gaps_are_reported() -> None:
    trace = scored(5)
    assert trace.scored_steps() == 5
    assert problems_of(trace) == []
    del trace.scores[ACE].windowed[3]
    trace.unknown_steps.add(3)
    problems = problems_of(trace)
    assert any("only 4 scored" in p for p in problems)
    assert any("UNKNOWN at steps [3]" in p for p in problems)
    silent = RolloutTrace("in-distribution", "id", 1, rollout_id=9)
    silent.steps_started = 2
    assert any("no rnd_oe score" in p for p in problems_of(silent))


def test_summary_dict_carries_both_series() -> None:
    data = scored(3, alarm=2).to_dict()
    assert data["rnd_oe"]["windowed"] == [0.0, 0.5, 1.0]
    assert data["ace"]["threshold"] == [6.0, 7.0, 8.0]
    assert data["alarm_step"] == 2 and data["scored_steps"] == 3
    assert data["detectors"] == ["rnd_oe", "ace"] and data["judged_by"] == "RND-OE and ACE"


@pytest.mark.parametrize(("combine", "judged"), [
    ("and", "RND-OE and ACE"), ("max", "RND-OE and ACE (max)"), ("or", "RND-OE and ACE (or)"),
    ("", "RND-OE and ACE (combine not known)"),
])
def test_the_summary_says_how_the_fusion_node_combined_the_pair(combine: str, judged: str) -> None:
    trace = scored(3, alarm=2)
    trace.combine = combine  # as the driver takes it from the alarms (FailureAlarm.combine)
    data = trace.to_dict()
    assert data["combine"] == combine and data["judged_by"] == judged


def test_an_observation_only_trace_keeps_and_waits_for_rnd_oe_alone() -> None:
    trace = scored(4, alarm=3, detectors=OBSERVATION_ONLY)
    assert set(trace.scores) == {RND_OE}
    assert trace.scored_steps() == 4 and problems_of(trace) == []  # no ACE score is missing: none is expected
    data = trace.to_dict()
    assert "ace" not in data and data["rnd_oe"]["windowed"] == [0.0, 0.5, 1.0, 1.5]
    assert data["detectors"] == ["rnd_oe"] and data["judged_by"] == "RND-OE alone (observation-only: no ACE)"
    del trace.scores[RND_OE].windowed[1]
    assert trace.scored_steps() == 3
    assert problems_of(trace) == [f"rollout {trace.rollout_id}: 4 policy steps, only 3 scored by rnd_oe"]
    assert RolloutTrace("x", "id", 1, detectors=()).scored_steps() == 0  # collect --ros without a calibration


def test_figure_is_written(tmp_path: Path) -> None:
    png = plot_trace(scored(8, alarm=5), tmp_path / "out" / "rollout.png", "sorting")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000


PAIR_TITLES = ["RND-OE: windowed observation score (eq. 2)", "ACE: windowed action-chunk entropy (eq. 5)"]


@pytest.mark.parametrize(("detectors", "combine", "titles", "judged"), [
    (DETECTORS, "and", PAIR_TITLES, "judged by RND-OE and ACE"),
    (DETECTORS, "max", PAIR_TITLES, "judged by RND-OE and ACE (max)"),
    (OBSERVATION_ONLY, "", ["RND-OE: windowed observation score (eq. 2)"],
     "judged by RND-OE alone (observation-only: no ACE)"),
])
def test_the_figure_draws_the_declared_detectors_and_says_which_are_absent(
        detectors: tuple[str, ...], combine: str, titles: list[str], judged: str, tmp_path: Path) -> None:
    trace = scored(8, alarm=5, detectors=detectors, combine=combine)
    figure = trace_figure(trace, "sorting")
    try:
        assert [axis.get_title() for axis in figure.axes] == titles
        for axis, name in zip(figure.axes, detectors, strict=True):
            (line, *_) = axis.get_lines()
            assert line.get_ydata().tolist() == list(trace.scores[name].windowed.values())
        assert figure.texts[0].get_text().endswith("\n" + judged)
    finally:
        plt.close(figure)
    png = plot_trace(trace, tmp_path / "rollout.png", "sorting")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_config_makes_model_and_calibration_absolute(tmp_path: Path) -> None:
    config = demo_config(DEMO_YAML, tmp_path / "model", tmp_path / "calibration", DETECTORS)
    nodes = {spec.name: spec for spec in config.nodes}
    assert set(nodes) == {"bridge_node", "policy_node", "rnd_oe_node", "ace_node", "fusion_node", "supervisor_node"}
    assert nodes["policy_node"].parameters["model"] == str(tmp_path / "model")
    for name in ("rnd_oe_node", "ace_node", "fusion_node"):  # the fusion node fuses the detectors it declares
        assert nodes[name].parameters["calibration_dir"] == str(tmp_path / "calibration")
    assert nodes["bridge_node"].namespace == "/sim" and nodes["bridge_node"].required
    assert all(spec.parameters.get("use_sim_time", False) == (name != "bridge_node") for name, spec in nodes.items())
    assert managed_nodes(config) == ["/sim/bridge_node", "/fiper/policy_node", "/fiper/rnd_oe_node", "/fiper/ace_node",
                                     "/fiper/fusion_node"]
    assert plain_nodes(config) == [SUPERVISOR]


def test_the_demo_with_its_live_view_waits_for_the_view_node_in_the_graph_only(tmp_path: Path) -> None:
    config = demo_config(DEMO_YAML, tmp_path / "model", tmp_path / "calibration", DETECTORS,
                         {"view": "true", "view_port": "0"})
    (view,) = [spec for spec in config.nodes if spec.name == "view_node"]
    assert (view.namespace, view.parameters["port"], view.parameters["host"], view.required) == \
        ("/fiper", 0, "127.0.0.1", False)  # the suite goes on without it
    assert VIEW not in managed_nodes(config) and plain_nodes(config) == [VIEW, SUPERVISOR]


def test_the_demo_of_an_observation_only_calibration_runs_no_ace_node(tmp_path: Path) -> None:
    config = demo_config(DEMO_YAML, tmp_path / "model", tmp_path / "calibration", OBSERVATION_ONLY)
    nodes = {spec.name: spec for spec in config.nodes}
    assert set(nodes) == {"bridge_node", "policy_node", "rnd_oe_node", "fusion_node", "supervisor_node"}
    assert nodes["fusion_node"].parameters["calibration_dir"] == str(tmp_path / "calibration")
    assert SUPERVISOR not in managed_nodes(config) and "/fiper/ace_node" not in managed_nodes(config)
    # the recorder waits for every topic it records: never for the scores of a detector that is not there
    assert suite_topics(OBSERVATION_ONLY) == tuple(t for t in TOPICS if t != SCORE_ACE_TOPIC)
    assert suite_topics(DETECTORS) == tuple(TOPICS) and SCORE_RND_OE_TOPIC in suite_topics(OBSERVATION_ONLY)


def test_the_progress_line_shows_the_declared_scores() -> None:
    msg = FailureAlarm(rollout_id=5, step=12, state=FailureAlarm.STATE_ALARM, detectors=list(DETECTORS),
                       eta=[3.25, 1.5], gamma=[2.5, 4.0], exceeded=[True, False])
    assert alarm_line(msg) == ("step  12 | RND-OE    3.250 /    2.500 > | ACE    1.500 /    4.000   "
                               "| ALARM")
    alone = FailureAlarm(rollout_id=5, step=3, state=FailureAlarm.STATE_OK, detectors=list(OBSERVATION_ONLY),
                         eta=[1.0], gamma=[2.5], exceeded=[False])
    assert alarm_line(alone) == "step   3 | RND-OE    1.000 /    2.500   | OK"
    three = FailureAlarm(rollout_id=5, step=4, state=FailureAlarm.STATE_UNKNOWN, detectors=["rnd_oe", "progress",
                         "elapsed"], eta=[1.0, 0.5, math.nan], gamma=[2.5, 0.25, 3.0], exceeded=[False, True, False])
    assert alarm_line(three) == ("step   4 | RND-OE    1.000 /    2.500   | progress    0.500 /    0.250 > "
                                 "| elapsed time      nan /    3.000   | UNKNOWN")


def test_events_pair_with_a_trace_whichever_comes_first() -> None:
    events = RolloutEvents()
    events.start(5, 100)
    events.end(5, 200, "failure")  # a halt right after the start, before the reset's answer
    early = events.follow(RolloutTrace("in-distribution", "id", 1, rollout_id=5))
    assert (early.ended, early.outcome, early.started_ns, early.ended_ns) == (True, "failure", 100, 200)
    late = events.follow(RolloutTrace("in-distribution", "id", 2, rollout_id=6))
    events.start(6, 300)
    assert not late.ended
    events.end(6, 400, "success")
    assert (late.outcome, late.started_ns, late.ended_ns) == ("success", 300, 400)


def test_an_early_end_of_another_rollout_ends_no_trace() -> None:
    events = RolloutEvents()
    events.end(7, 50, "failure")
    trace = events.follow(RolloutTrace("harmful OOD", "box_pos", 3, rollout_id=8))
    assert not trace.ended
    events.end(8, 60, "failure")
    assert trace.ended and events.follow(RolloutTrace("x", "id", 4, rollout_id=7)).ended


def test_messages_before_the_resets_answer_reach_their_trace() -> None:
    """Under load the first step's score came before the reset's answer and was dropped (the demo failed with
    "26 policy steps, only 25 scored by both detectors"): it is kept for the trace, and only for its own."""
    events = RolloutEvents()
    events.defer(5, lambda trace: trace.scores[RND_OE].add(0, 1.5, 3.0, False))
    events.defer(4, lambda trace: trace.scores[RND_OE].add(9, 9.0, 3.0, True))  # another rollout's late step
    trace = events.follow(RolloutTrace("in-distribution", "id", 1, rollout_id=5))
    assert trace.scores[RND_OE].windowed == {0: 1.5}
    other = events.follow(RolloutTrace("in-distribution", "id", 2, rollout_id=6))
    assert other.scores[RND_OE].windowed == {}


def test_early_messages_are_bounded_oldest_first() -> None:
    events = RolloutEvents()
    for step in range(EARLY_MESSAGES + 10):
        events.defer(5, lambda trace, step=step: trace.scores[ACE].add(step, float(step), 1.0, True))
    trace = events.follow(RolloutTrace("in-distribution", "id", 1, rollout_id=5))
    assert sorted(trace.scores[ACE].windowed) == list(range(10, EARLY_MESSAGES + 10))


def test_the_bag_is_complete_only_with_every_step_the_driver_saw_of_every_rollout() -> None:
    """The demo finishes its bag once it holds an embedding and an action batch of each policy step its traces saw:
    equal counts on both topics are not enough (a fresh-clone run's bag lacked the last step of a 16-step rollout,
    both of its messages still in flight to the recorder when the demo closed the bag on equal counts)."""
    traces = [scored(12, outcome="success"), scored(16)]
    assert recorded_every_step({EMBEDDING_TOPIC: 28, ACTIONS_TOPIC: 28}, traces)
    assert recorded_every_step({EMBEDDING_TOPIC: 29, ACTIONS_TOPIC: 28}, traces)
    assert not recorded_every_step({EMBEDDING_TOPIC: 27, ACTIONS_TOPIC: 27}, traces)
    assert not recorded_every_step({EMBEDDING_TOPIC: 28, ACTIONS_TOPIC: 27}, traces)
    assert not recorded_every_step({ACTIONS_TOPIC: 28}, traces)
    assert recorded_every_step({}, [])
