"""The demo's per-rollout record, its verdicts, its problems and its figure."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from fiper_ros.client.figure import plot_trace
from fiper_ros.client.trace import ACE, EARLY_MESSAGES, RND_OE, RolloutEvents, RolloutTrace
from fiper_ros.commands.demo import demo_config, problems_of
from fiper_ros.launcher.config import load_config


def scored(steps: int, alarm: int | None = None, outcome: str = "failure") -> RolloutTrace:
    trace = RolloutTrace("harmful OOD", "box_pos", 7, rollout_id=(1 << 32) | 7)
    for step in range(steps):
        trace.scores[RND_OE].add(step, 0.5 * step, 2.0, 0.5 * step > 2.0)
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


def test_figure_is_written(tmp_path: Path) -> None:
    png = plot_trace(scored(8, alarm=5), tmp_path / "out" / "rollout.png", "sorting")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert png.stat().st_size > 10_000


def test_demo_config_makes_model_and_calibration_absolute(tmp_path: Path) -> None:
    source = Path(__file__).resolve().parents[2] / "fiper_ros" / "config" / "demo.yaml"
    out = demo_config(source, tmp_path / "model", tmp_path / "calibration", tmp_path / "launch.yaml")
    nodes = {spec.name: spec for spec in load_config(out).nodes}
    assert set(nodes) == {"bridge_node", "policy_node", "rnd_oe_node", "ace_node", "fusion_node", "supervisor_node"}
    assert nodes["policy_node"].parameters["model"] == str(tmp_path / "model")
    assert nodes["ace_node"].parameters["calibration_dir"] == str(tmp_path / "calibration")
    assert nodes["bridge_node"].namespace == "/sim" and nodes["bridge_node"].required
    assert "calibration_dir" not in nodes["fusion_node"].parameters
    assert np.all([spec.parameter_files for spec in nodes.values()])


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
