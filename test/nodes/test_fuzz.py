"""Property-based fuzzing of every message the scoring, fusion and supervisor nodes subscribe to (issue #18).

The real node classes run in a private rclpy context; their subscription callbacks are called directly with
generated messages (``test/helpers/fuzz.py`` says why and how). Field values are arbitrary: NaN, infinities
and huge floats, zero, huge and lying sizes, random strings, uint32 / uint64 extremes for steps and rollout
ids, START and END of a few rollout ids interleaved with the steps. After every message:

- the node did not raise;
- every input is accounted for: scored, rejected and counted under a reason of
  :data:`fiper_ros.runtime.validation.REASONS` (``node.rejected``, what ``/diagnostics`` reports), or
  waiting: in the START wait buffer (within its bounds) or the joint-state gate (``joint_state_wait_s``);
- an input whose content is not valid never yields a finite score, a valid one never a NaN score;
- no FailureAlarm OK for a step whose input either scoring node rejected, whose window still holds a
  missing step of the detector that decides, before which a step went unjudged, or after an ALARM;
- memory stays within its configured bounds (START wait buffer, fusion buffer, joint history, rates).

After each example the same nodes judge a valid rollout exactly as the offline oracle
:func:`fiper_ros.core.monitor.predict_rollout` does: states, exceeded flags, windowed scores and thresholds as
float32.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import event, given, note
from hypothesis import strategies as st
from rclpy.context import Context
from rclpy.lifecycle import TransitionCallbackReturn
from sensor_msgs.msg import JointState
from sim_bridge.robot import URDF_PATH

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent, Score
from fiper_msgs.srv import ResetAlarm
from fiper_ros.core.calibration import Calibration, load_calibration
from fiper_ros.core.kinematics import PinocchioFK
from fiper_ros.core.monitor import RolloutPrediction, predict_rollout
from fiper_ros.core.rollout import Rollout
from fiper_ros.core.scores import JOINT_POSITIONS_KEY
from fiper_ros.interface.conversions import (action_batch_msg, embedding_msg, float_array, rollout_event_msg, stamp_ns,
                                             to_stamp)
from fiper_ros.nodes import ace_node, detector_node
from fiper_ros.nodes.ace_node import AceNode
from fiper_ros.nodes.fusion_node import FusionNode
from fiper_ros.nodes.rnd_oe_node import RndOeNode
from fiper_ros.nodes.supervisor_node import SupervisorNode
from fiper_ros.runtime.alarm import DETECTORS
from fiper_ros.runtime.rollout_tracker import RolloutTracker
from fiper_ros.runtime.supervision import HALTED_MEMORY
from fiper_ros.runtime.validation import DEFAULT_MAX_ABS_VALUE, REASONS
from helpers.fuzz import (FLOAT32, MOSTLY, NODE_KWARGS, STAMP, TEXT, UINT8, UINT32, UINT64, UINT64_MAX, bring_up,
                          callbacks, draw_payload, draw_step, fuzz, load_once, node_params, private_context, record)
from helpers.suite import STATE, assert_as_the_oracle
from helpers.synthetic import B, D, EXEC, H, make_rollout

#: Small bounds, so that the fuzz reaches them: the largest message, the values waiting for their START.
MAX_ELEMENTS = 4 * B * H * D
START_WAIT_VALUES = 3 * B * H * D
FUSION_BUFFER = 8
#: The valid rollouts judged after each example: ids the fuzz never uses.
VALID_ID = 2**40 + 7
#: The rollout ids the fuzz uses: few, so that STARTs, ENDs and steps of one rollout meet; and the extremes.
ROLLOUT_IDS = st.one_of(st.sampled_from([1, 2, 3]), st.sampled_from([0, UINT64_MAX]), UINT64).map(
    lambda rollout_id: rollout_id + 10 if VALID_ID <= rollout_id < VALID_ID + 10 else rollout_id)
#: A declared embedding shape whose product overflows int64 to exactly E = 16 (np.prod wraps silently).
WRAPPING_SHAPE = [16, 3702849463, 793907557, 251]
PIPELINE_INPUTS = st.sampled_from(["step", "step", "step", "embedding", "batch", "event", "event", "timer"])
#: The values of valid inputs: a synthetic rollout's embeddings and batches, out of distribution from FAIL_FROM on
#: (so that valid input gets judged ALARM as well as OK).
ROWS = make_rollout(900, fail=True)


@pytest.fixture
def context(ros_domain: int, monkeypatch: pytest.MonkeyPatch) -> Iterator[Context]:
    """A private rclpy context; the scoring nodes load each calibration (and URDF) once per test (``load_once``)."""
    load_once(monkeypatch, detector_node, "load_calibration")
    load_once(monkeypatch, ace_node, "PinocchioFK")
    with private_context(ros_domain) as ctx:
        yield ctx


# strategies: functions of ``draw`` (``data.draw`` of ``st.data()``), so that they can follow the nodes' state ------
_START, _END = RolloutEvent.EVENT_START, RolloutEvent.EVENT_END
_EVENT_KIND = st.one_of(st.sampled_from([_START, _START, _END]), UINT8)
_OUTCOME = st.one_of(st.integers(0, 2), UINT8)
_MAX_STEPS = st.one_of(st.sampled_from([0, 0, 3, 12, 40]), UINT32)
_TASK = st.one_of(st.sampled_from(["synthetic", "synthetic", ""]), TEXT)  # the calibration's, none, another
_SHAPES = st.sampled_from(["flat", "own", "own", "split", "wrong", "zero", "wrapping", "any"])
_ANY_SHAPE = st.lists(UINT32, max_size=4)
_BATCH_KINDS = st.sampled_from(["valid", "valid", "other_b", "fields", "dims"])


def draw_rollout_id(draw: st.DrawFn, tracker: RolloutTracker | None) -> int:
    """Mostly (3 in 4) the ``tracker``'s current rollout, else any id the fuzz uses."""
    current = None if tracker is None else tracker.current
    if current is not None and draw(MOSTLY):
        return current.rollout_id
    return draw(ROLLOUT_IDS)


def draw_event(draw: st.DrawFn, tracker: RolloutTracker | None = None) -> RolloutEvent:
    """A START or END (or an event or outcome code that means nothing) with arbitrary fields."""
    msg = RolloutEvent(rollout_id=draw_rollout_id(draw, tracker), event=draw(_EVENT_KIND), outcome=draw(_OUTCOME),
                       task=draw(_TASK), scenario=draw(TEXT), max_steps=draw(_MAX_STEPS))
    msg.header.stamp = draw(STAMP)
    return msg


def draw_address(draw: st.DrawFn, tracker: RolloutTracker, in_order: bool = False) -> tuple[int, int]:
    """A (rollout_id, step): mostly the node's current rollout near its next step, else anything; ``in_order``:
    mostly its very next step (a policy's steps, a gap now and then)."""
    rollout_id = draw_rollout_id(draw, tracker)
    current = tracker.current
    expected = 0
    if current is not None and current.rollout_id == rollout_id and current.last_step is not None:
        expected = current.last_step + 1
    return rollout_id, expected if in_order and draw(MOSTLY) else draw_step(draw, expected)


def draw_embedding(draw: st.DrawFn, tracker: RolloutTracker, tag: str,
                   address: tuple[int, int] | None = None) -> tuple[ObservationEmbedding, bool]:
    """An ObservationEmbedding (of ``address`` if given) and whether its content (values, declared shape) is valid."""
    rollout_id, step = address or draw_address(draw, tracker)
    valid = ROWS.embeddings[step % ROWS.length]
    if draw(MOSTLY):  # mostly valid, so that rollouts get judged OK and ALARM too
        data, ok, kind = valid, True, "own"
    else:
        data, ok = draw_payload(draw, valid, MAX_ELEMENTS, DEFAULT_MAX_ABS_VALUE)
        kind = draw(_SHAPES)
    shape = {"flat": [], "own": [data.size], "split": [4, data.size // 4], "wrong": [data.size + 1],
             "zero": [0, data.size], "wrapping": WRAPPING_SHAPE}.get(kind)
    if shape is None:
        shape = draw(_ANY_SHAPE)
    ok = ok and (not shape or (math.prod(shape) == data.size and min(shape) > 0))
    msg = ObservationEmbedding(rollout_id=rollout_id, step=step, data=float_array(data), shape=shape)
    msg.header.stamp = draw(STAMP)
    msg.header.frame_id = tag
    return msg, ok


def draw_batch(draw: st.DrawFn, tracker: RolloutTracker, tag: str, address: tuple[int, int] | None = None,
               space: str = "ee_position", rows: np.ndarray = ROWS.actions,
               max_elements: int = MAX_ELEMENTS) -> tuple[ActionChunkBatch, bool]:
    """An ActionChunkBatch (of ``address`` if given) and whether its content (values, B x H x D, h, action space)
    is valid."""
    rollout_id, step = address or draw_address(draw, tracker)
    b, h, d = rows.shape[1:]
    if draw(MOSTLY):  # mostly valid, so that rollouts get judged OK and ALARM too
        msg = action_batch_msg(rollout_id, step, 0, rows[step % len(rows)], EXEC, space)
        msg.header.stamp = draw(STAMP)
        msg.header.frame_id = tag
        return msg, True
    kind = draw(_BATCH_KINDS)
    if kind == "other_b":  # another number of samples: still valid
        b = draw(st.integers(1, 40))
        values = np.random.default_rng(draw(st.integers(0, 2**16))).normal(0.0, 0.5, (b, h, d)).astype(np.float32)
        data, ok = values.ravel(), True
    else:
        data, ok = draw_payload(draw, rows[step % len(rows)], max_elements, DEFAULT_MAX_ABS_VALUE)
    dims = [b, h, d]
    if kind == "fields":  # declared sizes that do not fit the data
        dims[draw(st.integers(0, 2))] = draw(UINT32)
    elif kind == "dims":  # the data as declared, of another H or D than the calibration's
        dims = [draw(st.integers(1, 6)), draw(st.sampled_from([h, h + 1, 1])), draw(st.sampled_from([d, d + 1, 1]))]
        data = np.zeros(math.prod(dims), np.float32)
        ok = True
    exec_steps = min(EXEC, dims[1]) if draw(st.booleans()) else draw(st.one_of(st.integers(0, 9), UINT32))
    action_space = space if draw(st.booleans()) else draw(st.one_of(st.sampled_from(
        ["ee_position", "joint_position", "joint_velocity", ""]), TEXT))
    ok = (ok and data.size == math.prod(dims) and dims[1:] == [h, d] and dims[0] >= 1 and 1 <= exec_steps <= dims[1]
          and action_space == space and data.size <= max_elements)
    msg = ActionChunkBatch(rollout_id=rollout_id, step=step, batch_size=dims[0], horizon=dims[1], action_dim=dims[2],
                           exec_steps=exec_steps, data=float_array(data), action_space=action_space)
    msg.header.stamp = draw(STAMP)
    msg.header.frame_id = tag
    return msg, ok


# the model of the contract ---------------------------------------------------------------------------
@dataclass
class Epoch:
    """One run of a rollout id, from a START that was not a repeat of the active rollout (or a reset)."""

    rollout_id: int
    verdicts: dict[int, str] = field(default_factory=dict)
    alarmed: bool = False
    ended: bool = False
    floor: int = 0
    """The first step that must have been judged before an OK (0; after a reset, the step after the last judged)."""
    last: tuple[int, str] | None = None
    """The last per-step verdict (step, state)."""


class VerdictModel:
    """What the alarm contract promises about FailureAlarm, checked message by message: the latch, no OK after
    an unjudged step, heartbeats that repeat the last verdict; what makes one step OK is :meth:`certain`'s."""

    def __init__(self) -> None:
        self.epoch: Epoch | None = None

    def on_event(self, msg: RolloutEvent) -> None:
        epoch = self.epoch
        if msg.event == RolloutEvent.EVENT_START:
            if epoch is None or epoch.rollout_id != msg.rollout_id or epoch.ended:
                self.epoch = Epoch(msg.rollout_id)
        elif msg.event == RolloutEvent.EVENT_END and epoch is not None and epoch.rollout_id == msg.rollout_id:
            epoch.ended = True

    def on_reset(self) -> None:
        epoch = self.epoch
        if epoch is not None:
            epoch.alarmed, epoch.last = False, None
            epoch.floor = max(epoch.verdicts, default=-1) + 1

    def on_alarm(self, msg: FailureAlarm) -> None:
        epoch, step, state = self.epoch, msg.step, STATE[msg.state]
        if msg.heartbeat:
            if state == "ok":
                assert epoch is not None and not epoch.ended and msg.rollout_id == epoch.rollout_id, \
                    f"OK heartbeat of no running rollout: {msg}"
                assert epoch.last == (step, "ok"), f"OK heartbeat that repeats no OK verdict: {msg}, {epoch.last}"
            return
        assert epoch is not None and msg.rollout_id == epoch.rollout_id, f"a verdict of no started rollout: {msg}"
        if state == "ok":
            assert not epoch.alarmed, f"OK at step {step} after an ALARM of this rollout"
            assert all(t in epoch.verdicts for t in range(epoch.floor, step)), \
                f"OK at step {step}: an earlier step was never judged"
            self.certain(msg)
        if state == "alarm" and not epoch.alarmed:
            self.exceeded(msg)
        epoch.alarmed |= state == "alarm"
        epoch.verdicts.setdefault(step, state)
        epoch.last = (step, state)

    def certain(self, msg: FailureAlarm) -> None:
        """Assert what an OK verdict of ``msg.step`` needs of the scores."""
        raise NotImplementedError

    def exceeded(self, msg: FailureAlarm) -> None:
        """Assert what the first ALARM verdict of a rollout needs of the scores of its step."""
        raise NotImplementedError


class PipelineContract(VerdictModel):
    """The contract over the whole pipeline: the scoring nodes' Scores (one per step and rollout, in order) and the
    fusion node's verdicts. OK needs both inputs of the step scored, and a window without a missing or rejected
    step in a detector that is below its threshold (any detector for AND, both for OR)."""

    def __init__(self, windows: dict[str, int], combine: str) -> None:
        super().__init__()
        self.windows = windows
        self.combine = combine
        self.scores: dict[str, dict[int, Score]] = {}

    def on_event(self, msg: RolloutEvent) -> None:
        epoch = self.epoch
        super().on_event(msg)
        if self.epoch is not epoch:
            self.scores = {d: {} for d in DETECTORS}

    def on_score(self, msg: Score) -> None:
        epoch, mine = self.epoch, self.scores.get(msg.detector, {})
        assert epoch is not None and msg.rollout_id == epoch.rollout_id, f"a Score of no started rollout: {msg}"
        assert msg.step not in mine, f"two Scores of {msg.detector} for step {msg.step}"
        assert not mine or msg.step > max(mine), f"{msg.detector}: step {msg.step} after {max(mine)}"
        mine[msg.step] = msg

    def certain(self, msg: FailureAlarm) -> None:
        step = msg.step
        pair = {d: self.scores[d].get(step) for d in DETECTORS}
        assert all(s is not None and math.isfinite(s.score) for s in pair.values()), \
            f"OK at step {step} whose input was rejected: {pair}"
        below = [d for d in DETECTORS if not pair[d].exceeded and all(
            t in self.scores[d] and math.isfinite(self.scores[d][t].score)
            for t in range(max(0, step - self.windows[d] + 1), step + 1))]
        assert (below if self.combine == "and" else len(below) == len(DETECTORS)), \
            f"OK at step {step} though no detector is certainly below its threshold: {pair}"

    def exceeded(self, msg: FailureAlarm) -> None:
        pair = [self.scores[d].get(msg.step) for d in DETECTORS]
        exceeded = [s is not None and s.exceeded for s in pair]
        assert all(exceeded) if self.combine == "and" else any(exceeded), f"ALARM at step {msg.step} of {pair}"


class ScoringLedger:
    """Accounts for every input given to one scoring node (by the ``frame_id`` tag the Score copies)."""

    def __init__(self, node: Any, *then: Callable[[Score], None], held: Callable[[], int] = lambda: 0) -> None:
        self.node = node
        self.published = record(node._score_pub, self._on_score, *then)
        """The Scores the node published (each also passed to ``then``)."""
        self.held = held
        """How many inputs the node holds besides its START wait buffer (the joint-state gate)."""
        self.content_ok: dict[str, bool | None] = {}
        self.other_rejections = 0
        """Rejections of other messages than the scored inputs (joint states)."""

    def sent(self, tag: str, ok: bool | None) -> None:
        """Input ``tag`` is given; ``ok``: whether it must be scored (True), must not be (False), or either (None)."""
        self.content_ok[tag] = ok

    def _on_score(self, msg: Score) -> None:
        # A rollout whose START names another task than the calibration's may have its valid steps rejected too.
        current, tasks = self.node.gate.current, self.node.calibration.named_tasks
        if current is not None and current.task and tasks and current.task not in tasks:
            self.content_ok[msg.header.frame_id] = self.content_ok[msg.header.frame_id] and None

    def check(self) -> None:
        node = self.node
        assert set(node.rejected) <= set(REASONS), node.rejected
        tags = [s.header.frame_id for s in self.published]
        assert len(tags) == len(set(tags)), "an input was scored twice"
        finite = [s for s in self.published if math.isfinite(s.score)]
        for score in self.published:
            ok = self.content_ok[score.header.frame_id]
            assert ok is None or math.isfinite(score.score) == ok, (score, ok)  # bad input never scores, good does
        waiting = len(node.gate.waiting) + self.held()
        assert len(self.content_ok) == len(finite) + node.rejected.total() - self.other_rejections + waiting, \
            (len(self.content_ok), len(finite), node.rejected, waiting)
        assert len(node.gate.waiting) <= node.gate.waiting.max_items
        assert node.gate.waiting._size <= node.gate.waiting.max_size


# the pipeline -----------------------------------------------------------------------------------------
class Pipeline:
    """The RND-OE, ACE and fusion nodes, wired by direct calls: a Score a scoring node publishes reaches the
    fusion node's callback at once, a RolloutEvent reaches all three."""

    def __init__(self, context: Context, calibration: Calibration, calibration_dir: Path) -> None:
        scoring = node_params(calibration_dir=str(calibration_dir), max_elements=MAX_ELEMENTS, start_wait_s=60.0,
                              start_wait_max_elements=START_WAIT_VALUES)
        self.rnd = bring_up(RndOeNode(context=context, namespace="/fiper", parameter_overrides=scoring, **NODE_KWARGS))
        self.ace = bring_up(AceNode(context=context, namespace="/fiper", parameter_overrides=scoring, **NODE_KWARGS))
        self.fusion = bring_up(FusionNode(context=context, namespace="/fiper", parameter_overrides=node_params(
            buffer_size=FUSION_BUFFER, start_wait_s=60.0), **NODE_KWARGS))
        self.contract = PipelineContract({"rnd_oe": calibration.settings.window_of("rnd_oe"),
                                          "ace": calibration.settings.window_of("ace")}, calibration.settings.combine)
        self.alarms = record(self.fusion._alarm_pub, self.contract.on_alarm)
        fusion_in = callbacks(self.fusion)
        self.ledgers = {}
        for node in (self.rnd, self.ace):
            topic = f"/fiper/scores/{node.settings.detector}"
            self.ledgers[node.settings.detector] = ScoringLedger(node, self.contract.on_score, fusion_in[topic])
        self.inputs = {"embedding": callbacks(self.rnd)["/fiper/observation_embedding"],
                       "batch": callbacks(self.ace)["/fiper/action_chunks"]}
        self.event_callbacks = [callbacks(n)["/fiper/rollout_events"] for n in (self.rnd, self.ace, self.fusion)]
        self.count = 0

    def nodes(self) -> tuple[Any, ...]:
        return self.rnd, self.ace, self.fusion

    def event(self, msg: RolloutEvent) -> None:
        note(f"event {msg.event} of rollout {msg.rollout_id} (max_steps {msg.max_steps})")
        self.contract.on_event(msg)
        for call in self.event_callbacks:
            call(msg)

    def send(self, kind: str, msg: Any, ok: bool) -> None:
        note(f"{msg.header.frame_id}: {kind} of rollout {msg.rollout_id} step {msg.step}, {'valid' if ok else 'bad'}")
        self.ledgers["rnd_oe" if kind == "embedding" else "ace"].sent(msg.header.frame_id, ok)
        self.inputs[kind](msg)

    def check(self) -> None:
        for ledger in self.ledgers.values():
            ledger.check()
        fusion = self.fusion
        assert set(fusion.rejected) <= set(REASONS), fusion.rejected
        assert len(fusion.fuser._pending) <= FUSION_BUFFER
        assert len(fusion.fuser.gate.waiting) <= fusion.fuser.gate.waiting.max_items
        assert set(fusion.rates) <= {f"scores/{d}" for d in DETECTORS}, sorted(fusion.rates)

    def judge(self, rollout: Rollout, rollout_id: int) -> dict[int, FailureAlarm]:
        """Run a valid rollout through the pipeline; its per-step verdicts."""
        first = len(self.alarms)
        self.event(rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, 0, task="synthetic"))
        for t in range(rollout.length):
            stamp = (t + 1) * 100_000_000
            embedding = embedding_msg(rollout_id, t, stamp, rollout.embeddings[t])
            batch = action_batch_msg(rollout_id, t, stamp, rollout.actions[t], rollout.exec_steps, "ee_position")
            for kind, msg in (("embedding", embedding), ("batch", batch)):
                msg.header.frame_id = f"valid {rollout_id} {t}"
                self.send(kind, msg, True)
        self.event(rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, 0, outcome=RolloutEvent.OUTCOME_SUCCESS))
        return {m.step: m for m in self.alarms[first:] if m.rollout_id == rollout_id and not m.heartbeat}

    def close(self) -> None:
        for node in self.nodes():
            node.destroy_node()


class Oracle:
    """The calibration and valid rollouts with their offline predictions."""

    def __init__(self, calibration: Calibration, cases: list[tuple[Rollout, RolloutPrediction]]) -> None:
        self.calibration = calibration
        self.cases = cases

    def __repr__(self) -> str:  # hypothesis prints every example's arguments: keep the arrays out of it
        return f"Oracle({len(self.cases)} rollouts)"


@pytest.fixture(scope="module")
def oracle(calibration_dir: Path) -> Oracle:
    calibration = load_calibration(calibration_dir)
    rollouts = [make_rollout(910), make_rollout(911, fail=True)]
    return Oracle(calibration, [(r, predict_rollout(r, calibration)) for r in rollouts])


@fuzz(30)
@given(data=st.data())
def test_the_scoring_and_fusion_nodes_survive_any_input_and_never_say_ok_for_a_rejected_step(
        context: Context, calibration_dir: Path, oracle: Oracle, data: st.DataObject) -> None:
    pipeline = Pipeline(context, oracle.calibration, calibration_dir)
    try:
        for n in range(data.draw(st.integers(1, 50), label="messages")):
            kind = data.draw(PIPELINE_INPUTS)
            if kind == "event":
                pipeline.event(draw_event(data.draw, pipeline.rnd.gate))
            elif kind == "timer":
                note("timer")
                pipeline.fusion._on_timer()
                for node in pipeline.nodes():
                    node.publish_diagnostics()
            elif kind == "step":  # a policy step: an embedding and a batch of one (rollout_id, step)
                address = draw_address(data.draw, pipeline.rnd.gate, in_order=True)
                for part, make in (("embedding", draw_embedding), ("batch", draw_batch)):
                    msg, ok = make(data.draw, pipeline.rnd.gate, f"m{n} {part}", address)
                    pipeline.send(part, msg, ok)
                    pipeline.check()
            else:
                make, node = (draw_embedding, pipeline.rnd) if kind == "embedding" else (draw_batch, pipeline.ace)
                msg, ok = make(data.draw, node.gate, f"m{n}")
                pipeline.send(kind, msg, ok)
            pipeline.check()
        oks = sum(not m.heartbeat and m.state == FailureAlarm.STATE_OK for m in pipeline.alarms)
        event(f"OK verdicts: {min(3, oks)}")  # --hypothesis-show-statistics: how many examples reach OK
        for i, (rollout, prediction) in enumerate(oracle.cases):
            assert_as_the_oracle(pipeline.judge(rollout, VALID_ID + i), prediction)
            pipeline.check()
    finally:
        pipeline.close()


# the fusion node alone: arbitrary Scores ------------------------------------------------------------------
_DETECTOR = st.one_of(st.sampled_from(DETECTORS), st.sampled_from(DETECTORS), TEXT)
_SCORE = st.one_of(st.floats(0, 20, width=32), FLOAT32)
_WINDOWED = st.one_of(st.floats(0, 40, width=32), FLOAT32)
_THRESHOLD = st.one_of(st.sampled_from([15.0, 30.0]), st.floats(0, 40, width=32), FLOAT32)
FUSION_INPUTS = st.sampled_from(["pair", "pair", "pair", "score", "event", "event", "timer", "reset"])


def same(a: float, b: float) -> bool:
    """Equal as float32 numbers, NaN equal to NaN."""
    return (math.isnan(a) and math.isnan(b)) or np.float32(a) == np.float32(b)


def draw_score(draw: st.DrawFn, fusion: FusionNode, detector: str | None = None,
               address: tuple[int, int] | None = None) -> Score:
    """A Score of arbitrary fields: mostly of the fusion node's rollout near its next step, with an ``exceeded``
    flag that mostly agrees with the numbers."""
    fuser = fusion.fuser
    if address is None:
        rollout_id = fuser.rollout_id if fuser.rollout_id is not None and draw(MOSTLY) else draw(ROLLOUT_IDS)
        address = rollout_id, draw_step(draw, fuser._next_step if rollout_id == fuser.rollout_id else 0)
    windowed, threshold = draw(_WINDOWED), draw(_THRESHOLD)
    exceeded = bool(np.float32(windowed) > np.float32(threshold)) if draw(MOSTLY) else draw(st.booleans())
    msg = Score(rollout_id=address[0], step=address[1], detector=detector or draw(_DETECTOR), score=draw(_SCORE),
                windowed_score=windowed, threshold=threshold, exceeded=exceeded, window=draw(UINT32),
                complete=draw(MOSTLY), latency_ms=draw(FLOAT32))
    msg.header.stamp = draw(STAMP)
    return msg


class FusionContract(VerdictModel):
    """The contract for a fusion node fed arbitrary Scores: a verdict's numbers are those of Scores it received for
    that step (the fused pair), and OK, or a first ALARM, needs what eq. (7) and the contract say of them."""

    def __init__(self, combine: str) -> None:
        super().__init__()
        self.combine = combine
        self.received: dict[tuple[int, int, str], list[Score]] = {}

    def on_score(self, msg: Score) -> None:
        self.received.setdefault((msg.rollout_id, msg.step, msg.detector), []).append(msg)

    def pair(self, msg: FailureAlarm) -> dict[str, list[Score]]:
        """Per detector, the received Scores the verdict's numbers can come from."""
        numbers = {"rnd_oe": (msg.eta_obs, msg.gamma_obs), "ace": (msg.eta_act, msg.gamma_act)}
        pair = {d: [s for s in self.received.get((msg.rollout_id, msg.step, d), [])
                    if same(s.windowed_score, numbers[d][0]) and same(s.threshold, numbers[d][1])] for d in DETECTORS}
        assert all(pair.values()), f"verdict {msg} of numbers no Score of its step carried"
        return pair

    def certain(self, msg: FailureAlarm) -> None:
        flags = {"rnd_oe": msg.obs_exceeded, "ace": msg.act_exceeded}
        pair = self.pair(msg)
        for d, scores in pair.items():
            assert any(math.isfinite(s.score) and math.isfinite(s.windowed_score) and math.isfinite(s.threshold)
                       and s.exceeded == flags[d] and (s.exceeded or s.windowed_score <= s.threshold)
                       for s in scores), f"OK at step {msg.step} from a rejected or undecidable {d} score: {scores}"
        below = [d for d in DETECTORS if not flags[d] and any(s.complete for s in pair[d])]
        assert (below if self.combine == "and" else len(below) == len(DETECTORS)), f"OK of {msg}: {pair}"

    def exceeded(self, msg: FailureAlarm) -> None:
        flags = {"rnd_oe": msg.obs_exceeded, "ace": msg.act_exceeded}
        assert all(flags.values()) if self.combine == "and" else any(flags.values()), f"ALARM without eq. 7: {msg}"
        for d, scores in self.pair(msg).items():
            assert not flags[d] or any(s.exceeded and s.windowed_score >= s.threshold for s in scores), \
                f"ALARM of {msg} from a {d} score that does not exceed: {scores}"


@fuzz(30)
@given(data=st.data())
def test_the_fusion_node_survives_any_score_and_keeps_the_contract(context: Context, oracle: Oracle,
                                                                   data: st.DataObject) -> None:
    fusion = bring_up(FusionNode(context=context, namespace="/fiper", parameter_overrides=node_params(
        buffer_size=FUSION_BUFFER, start_wait_s=60.0), **NODE_KWARGS))
    contract = FusionContract(fusion.fuser.combine)
    alarms = record(fusion._alarm_pub, contract.on_alarm)
    inputs = callbacks(fusion)
    on_event = inputs["/fiper/rollout_events"]

    def send(msg: Score) -> None:
        note(f"score {msg.detector!r} of rollout {msg.rollout_id} step {msg.step}: {msg.score} {msg.windowed_score} "
             f"{msg.threshold} exceeded={msg.exceeded} complete={msg.complete}")
        contract.on_score(msg)
        rejected, waiting = fusion.rejected.total(), len(fusion.fuser.gate.waiting)
        foreign = msg.rollout_id != fusion.fuser.rollout_id
        inputs[f"/fiper/scores/{msg.detector}" if msg.detector in DETECTORS else "/fiper/scores/rnd_oe"](msg)
        if msg.detector not in DETECTORS:
            assert fusion.rejected.total() == rejected + 1 and fusion.rejected["unknown_detector"] >= 1
        elif foreign:  # a Score of another rollout than the fusion node's waits for its START, or is counted
            assert fusion.rejected.total() + len(fusion.fuser.gate.waiting) >= rejected + waiting + 1, \
                f"a Score of rollout {msg.rollout_id} (not the current {fusion.fuser.rollout_id}) vanished"

    try:
        for _ in range(data.draw(st.integers(1, 60), label="messages")):
            kind = data.draw(FUSION_INPUTS)
            if kind == "event":
                msg = draw_event(data.draw)
                if fusion.fuser.rollout_id is not None and data.draw(MOSTLY):
                    msg.rollout_id = fusion.fuser.rollout_id
                note(f"event {msg.event} of rollout {msg.rollout_id}")
                contract.on_event(msg)
                on_event(msg)
            elif kind == "timer":
                fusion._on_timer()
                fusion.publish_diagnostics()
            elif kind == "reset":
                note("reset")
                contract.on_reset()
                request = ResetAlarm.Request(requester="test_fuzz", reason="a fuzzed reset")
                assert fusion._on_reset(request, ResetAlarm.Response()).success
            elif kind == "score":
                send(draw_score(data.draw, fusion))
            else:  # the two Scores of one step, in either order
                first = draw_score(data.draw, fusion, data.draw(st.sampled_from(DETECTORS)))
                send(first)
                send(draw_score(data.draw, fusion, DETECTORS[1 - DETECTORS.index(first.detector)],
                                (first.rollout_id, first.step)))
            assert set(fusion.rejected) <= set(REASONS), fusion.rejected
            assert len(fusion.fuser._pending) <= FUSION_BUFFER
            assert len(fusion.fuser.gate.waiting) <= fusion.fuser.gate.waiting.max_items
            assert set(fusion.rates) <= {f"scores/{d}" for d in DETECTORS}, sorted(fusion.rates)
        # afterwards: the Scores of valid rollouts, as the scoring nodes would publish them, are judged as offline
        for i, (rollout, prediction) in enumerate(oracle.cases):
            rollout_id, first = VALID_ID + i, len(alarms)
            for event_msg in [rollout_event_msg(rollout_id, RolloutEvent.EVENT_START, 0)]:
                contract.on_event(event_msg)
                on_event(event_msg)
            for t in range(rollout.length):
                for d, (scores, windowed, thresholds, exceeded) in (
                        ("rnd_oe", (prediction.detectors["rnd_oe"].scores, prediction.detectors["rnd_oe"].windowed, prediction.detectors["rnd_oe"].thresholds,
                                    prediction.detectors["rnd_oe"].exceeded)),
                        ("ace", (prediction.detectors["ace"].scores, prediction.detectors["ace"].windowed, prediction.detectors["ace"].thresholds,
                                 prediction.detectors["ace"].exceeded))):
                    valid = Score(rollout_id=rollout_id, step=t, detector=d, score=float(scores[t]),
                                  windowed_score=float(windowed[t]), threshold=float(thresholds[t]),
                                  exceeded=bool(exceeded[t]), window=3, complete=True)
                    contract.on_score(valid)
                    inputs[f"/fiper/scores/{d}"](valid)
            end = rollout_event_msg(rollout_id, RolloutEvent.EVENT_END, 0)
            contract.on_event(end)
            on_event(end)
            verdicts = {m.step: m for m in alarms[first:] if m.rollout_id == rollout_id and not m.heartbeat}
            assert_as_the_oracle(verdicts, prediction)
    finally:
        fusion.destroy_node()


# the ACE node on joint velocities: batches, joint states, events ----------------------------------------------
STACKING = Path(__file__).resolve().parents[2] / "models" / "stacking" / "calibration"
CHAIN = [f"panda_joint{i}" for i in range(1, 8)]
FINGERS = ["panda_finger_joint1", "panda_finger_joint2"]
Q0 = np.array([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, 0.8])
VELOCITIES = np.random.default_rng(7).normal(0.0, 0.3, (20, 8, 8, 8)).astype(np.float32)
STAMP_MS = 100_000_000
_POOLED_STAMP = st.integers(0, 30).map(lambda k: to_stamp(k * STAMP_MS))
_JOINT_NAMES = st.sampled_from(["chain", "chain", "shuffled", "fingers", "missing", "any"])
_JOINT_VALUES = st.sampled_from(["valid", "valid", "nan", "huge", "shorter", "longer", "empty"])
JV_INPUTS = st.sampled_from(["batch", "batch", "joints", "joints", "event", "timer"])


def draw_joint_state(draw: st.DrawFn) -> tuple[JointState, str]:
    """A JointState and what the ACE node must do with it: "take" it, "reject" it, or "ignore" it (not a position
    of every joint of the chain)."""
    names = {"chain": CHAIN, "shuffled": draw(st.permutations(CHAIN)), "fingers": CHAIN + FINGERS,
             "missing": CHAIN[:-1]}.get(draw(_JOINT_NAMES))
    if names is None:
        names = draw(st.lists(st.one_of(st.sampled_from(CHAIN), TEXT), max_size=9, unique=True))
    q = dict(zip(CHAIN, Q0 + draw(st.floats(-0.2, 0.2))))
    values = [q.get(name, 0.01) for name in names]
    kind = draw(_JOINT_VALUES)
    if kind in ("nan", "huge") and values:
        values[draw(st.integers(0, len(values) - 1))] = math.nan if kind == "nan" else 1e9
    elif kind == "shorter":
        values = values[:-1]
    elif kind == "longer":
        values = values + [0.0]
    elif kind == "empty":
        values = []
    msg = JointState(name=names, position=values)
    msg.header.stamp = draw(_POOLED_STAMP) if draw(MOSTLY) else draw(STAMP)
    if values and len(values) != len(names):
        return msg, "reject"
    if not set(CHAIN) <= set(names) or not values:
        return msg, "ignore"
    if not all(math.isfinite(v) and abs(v) <= DEFAULT_MAX_ABS_VALUE
                                            for name, v in zip(names, values) if name in CHAIN):
        return msg, "reject"
    return msg, "take"


@pytest.fixture(scope="module")
def stacking() -> Oracle:
    """The joint-velocity calibration and a valid rollout of it (joint positions measured at each step)."""
    calibration, length = load_calibration(STACKING), 12
    q = Q0 + 0.01 * np.arange(length)[:, None]
    rollout = Rollout("valid", "stacking", "id", np.zeros((length, calibration.layout.embedding_dim), np.float32),
                      VELOCITIES[:length], 4, True, "joint_velocity", {JOINT_POSITIONS_KEY: q})
    return Oracle(calibration, [(rollout, predict_rollout(rollout, calibration, PinocchioFK(URDF_PATH, "panda_hand")))])


@fuzz(20)
@given(data=st.data())
def test_the_joint_velocity_ace_node_survives_any_batch_and_joint_state(context: Context, stacking: Oracle,
                                                                       data: st.DataObject) -> None:
    ace = bring_up(AceNode(context=context, namespace="/fiper", parameter_overrides=node_params(
        calibration_dir=str(STACKING), urdf_path=str(URDF_PATH), joint_state_wait_s=10.0, max_elements=MAX_ELEMENTS,
        start_wait_s=60.0, start_wait_max_elements=START_WAIT_VALUES), **NODE_KWARGS))
    gate = ace._gate._queue
    # The gate holds batches (as the wire codec's views) and the events that came after one.
    ledger = ScoringLedger(ace, held=lambda: sum(not isinstance(item[3], RolloutEvent) for item in gate))
    scores = ledger.published
    try:
        for n in range(data.draw(st.integers(1, 40), label="messages")):
            topics = callbacks(ace)
            kind = data.draw(JV_INPUTS)
            if kind == "event":
                msg = draw_event(data.draw, ace.gate)
                note(f"event {msg.event} of rollout {msg.rollout_id}")
                topics["/fiper/rollout_events"](msg)
            elif kind == "timer":
                ace._release()  # the gate's timer callback
                ace.publish_diagnostics()
            elif kind == "joints":
                msg, fate = draw_joint_state(data.draw)
                note(f"joint state {list(msg.name)} {list(msg.position)} at {stamp_ns(msg.header.stamp)}: {fate}")
                joints = ace._joints
                history = joints._stamps[:], [id(q) for q in joints._positions]
                topics["/joint_states"](msg)
                ledger.other_rejections += fate == "reject"  # the ledger's count checks it was rejected
                taken = joints.at(stamp_ns(msg.header.stamp))
                if fate == "take":
                    assert taken is not None and list(taken) == [dict(zip(msg.name, msg.position))[j] for j in CHAIN]
                else:
                    assert (joints._stamps, [id(q) for q in joints._positions]) == history, fate
            else:
                msg, ok = draw_batch(data.draw, ace.gate, f"m{n}", space="joint_velocity", rows=VELOCITIES)
                msg.header.stamp = data.draw(_POOLED_STAMP) if data.draw(MOSTLY) else msg.header.stamp
                known = ace._joints.at(stamp_ns(msg.header.stamp)) is not None
                note(f"m{n}: batch of rollout {msg.rollout_id} step {msg.step} at {stamp_ns(msg.header.stamp)}: "
                     f"{'valid' if ok else 'bad'}{'' if known else ', no joint state yet'}")
                ledger.sent(msg.header.frame_id, ok if known or not ok else None)
                topics["/fiper/action_chunks"](msg)
            ledger.check()
            assert len(ace._joints) <= ace._joints.capacity
        assert ace.trigger_deactivate() == TransitionCallbackReturn.SUCCESS  # releases every batch the gate holds
        assert not gate and ace.trigger_activate() == TransitionCallbackReturn.SUCCESS
        ledger.check()
        # afterwards: a valid rollout is scored as offline
        (rollout, prediction), = stacking.cases
        topics, length, q = callbacks(ace), rollout.length, rollout.metadata[JOINT_POSITIONS_KEY]
        first = len(scores)
        topics["/fiper/rollout_events"](rollout_event_msg(VALID_ID, RolloutEvent.EVENT_START, 0))
        for t in range(length):
            stamp = (t + 1) * STAMP_MS + 7  # stamps the fuzz never drew
            state = JointState(name=CHAIN, position=list(q[t]))
            state.header.stamp = to_stamp(stamp)
            topics["/joint_states"](state)
            batch = action_batch_msg(VALID_ID, t, stamp, VELOCITIES[t], 4, "joint_velocity")
            batch.header.frame_id = f"valid {t}"
            ledger.sent(batch.header.frame_id, True)
            topics["/fiper/action_chunks"](batch)
        got = [m for m in scores[first:] if m.rollout_id == VALID_ID]
        assert [m.step for m in got] == list(range(length))
        for t, m in enumerate(got):
            assert (m.score, m.windowed_score, m.threshold, m.exceeded, m.complete) == (
                np.float32(prediction.detectors["ace"].scores[t]), np.float32(prediction.detectors["ace"].windowed[t]),
                np.float32(prediction.detectors["ace"].thresholds[t]), prediction.detectors["ace"].exceeded[t], True), t
        ledger.check()
    finally:
        ace.destroy_node()


# the example supervisor: alarms and rollout events -----------------------------------------------------------
_ALARM_STATE = st.one_of(st.sampled_from([FailureAlarm.STATE_OK, FailureAlarm.STATE_ALARM, FailureAlarm.STATE_UNKNOWN]),
                         UINT8)
SUPERVISOR_INPUTS = st.sampled_from(["alarm", "alarm", "alarm", "event", "clock"])


def draw_alarm(draw: st.DrawFn, supervisor: SupervisorNode) -> FailureAlarm:
    """A FailureAlarm of arbitrary fields, mostly of the rollout the supervisor follows."""
    followed = supervisor.logic._running
    rollout_id = followed if followed is not None and draw(MOSTLY) else draw(ROLLOUT_IDS)
    msg = FailureAlarm(rollout_id=rollout_id, step=draw(st.one_of(st.integers(0, 30), UINT32)),
                       state=draw(_ALARM_STATE),
                       latched=draw(st.booleans()), obs_exceeded=draw(st.booleans()), act_exceeded=draw(st.booleans()),
                       eta_obs=draw(FLOAT32), gamma_obs=draw(FLOAT32), eta_act=draw(FLOAT32), gamma_act=draw(FLOAT32),
                       combine=draw(TEXT), reason=draw(TEXT), heartbeat=draw(st.booleans()))
    msg.header.stamp = draw(STAMP)
    return msg


@fuzz(25)
@given(data=st.data())
def test_the_supervisor_survives_any_alarm_and_halts_on_the_first_alarm_of_a_rollout(
        context: Context, oracle: Oracle, data: st.DataObject) -> None:
    supervisor = SupervisorNode(context=context, **NODE_KWARGS)
    topics = callbacks(supervisor)
    try:
        for _ in range(data.draw(st.integers(1, 60), label="messages")):
            kind, before = data.draw(SUPERVISOR_INPUTS), len(supervisor.halts)
            if kind == "alarm":
                msg = draw_alarm(data.draw, supervisor)
                note(f"alarm {msg.state} of rollout {msg.rollout_id} step {msg.step} heartbeat={msg.heartbeat}")
                topics["/fiper/alarm"](msg)
                if msg.state == FailureAlarm.STATE_ALARM and len(supervisor.halts) == before:  # halted it before
                    assert msg.rollout_id in [h.rollout_id for h in supervisor.halts], msg
            elif kind == "event":
                msg = draw_event(data.draw)
                note(f"event {msg.event} of rollout {msg.rollout_id}")
                topics["/fiper/rollout_events"](msg)
            else:
                supervisor._on_clock()  # its timer's callback
            assert len(supervisor.halts) <= HALTED_MEMORY
            assert len(supervisor.halts) <= before + 1, "more than one halt for one message"
            halted = [h.rollout_id for h in supervisor.halts if not h.reason.startswith("no alarm message")]
            assert len(halted) == len(set(halted)), f"a rollout halted twice: {supervisor.halts}"
        # afterwards: the verdicts of a failing rollout halt it once, at its first ALARM, and none before
        rollout, prediction = oracle.cases[1]
        alarm_step = prediction.first_alarm_step
        assert alarm_step is not None
        topics["/fiper/rollout_events"](rollout_event_msg(VALID_ID, RolloutEvent.EVENT_START, 0))
        latched = np.logical_or.accumulate(prediction.alarms)
        for t in range(rollout.length):
            before = [h for h in supervisor.halts if h.rollout_id == VALID_ID]
            assert not before if t <= alarm_step else len(before) == 1, (t, before)
            state = FailureAlarm.STATE_ALARM if latched[t] else FailureAlarm.STATE_OK
            topics["/fiper/alarm"](FailureAlarm(rollout_id=VALID_ID, step=t, state=state, latched=bool(latched[t])))
        halts = [h for h in supervisor.halts if h.rollout_id == VALID_ID]
        assert len(halts) == 1 and halts[0].reason.startswith("ALARM"), halts
    finally:
        supervisor.destroy_node()


# what the fuzzing found, each as a focused regression test -------------------------------------------------
def test_scores_of_unknown_detectors_are_counted_and_do_not_grow_the_rate_meters(context: Context) -> None:
    # The fusion node made a rate meter (and a rate_hz.* diagnostics key) per detector name a Score carried,
    # before it rejected the unknown ones: memory and /diagnostics grew with every new name.
    fusion = bring_up(FusionNode(context=context, namespace="/fiper", parameter_overrides=node_params(),
                                 **NODE_KWARGS))
    try:
        on_score = callbacks(fusion)["/fiper/scores/rnd_oe"]
        for n in range(100):
            on_score(Score(rollout_id=1, step=0, detector=f"detector {n}"))
        assert fusion.rejected == {"unknown_detector": 100}
        assert not fusion.rates, sorted(fusion.rates)
    finally:
        fusion.destroy_node()


def test_scores_of_no_current_rollout_are_counted_as_unknown_rollout(context: Context) -> None:
    # The fusion node dropped a late Score of a rollout that had ended before the current one started without a
    # word, and counted Scores whose START never came only as dropped_without_start, outside rejected.*.
    fusion = bring_up(FusionNode(context=context, namespace="/fiper", parameter_overrides=node_params(),
                                 **NODE_KWARGS))
    try:
        on_score, on_event = callbacks(fusion)["/fiper/scores/ace"], callbacks(fusion)["/fiper/rollout_events"]
        for rollout_id, event in ((1, RolloutEvent.EVENT_START), (1, RolloutEvent.EVENT_END),
                                  (2, RolloutEvent.EVENT_START)):
            on_event(rollout_event_msg(rollout_id, event, 0))
        on_score(Score(rollout_id=1, step=3, detector="ace"))  # late: rollout 2 runs
        assert fusion.rejected == {"unknown_rollout": 1}
        for step in range(fusion.fuser.gate.waiting.max_items + 1):  # rollout 9 never starts: one drops out of the wait
            on_score(Score(rollout_id=9, step=step, detector="ace"))
        assert fusion.rejected == {"unknown_rollout": 2} and len(fusion.fuser.gate.waiting) == fusion.fuser.gate.waiting.max_items
    finally:
        fusion.destroy_node()


def test_a_joint_state_of_fewer_positions_than_names_is_rejected(context: Context) -> None:
    # The ACE node paired names with positions with zip(): a JointState naming the seven arm joints with six
    # positions lost the last joint and was dropped without a count.
    ace = bring_up(AceNode(context=context, namespace="/fiper", parameter_overrides=node_params(
        calibration_dir=str(STACKING), urdf_path=str(URDF_PATH)), **NODE_KWARGS))
    try:
        msg = JointState(name=CHAIN, position=list(Q0[:-1]))
        callbacks(ace)["/joint_states"](msg)
        assert ace.rejected == {"shape": 1} and len(ace._joints) == 0
    finally:
        ace.destroy_node()


def test_the_supervisor_keeps_a_bounded_record_of_its_halts(context: Context) -> None:
    # The example supervisor appended every halt to a list: one ALARM of each new rollout id grew it for ever.
    supervisor = SupervisorNode(context=context, **NODE_KWARGS)
    try:
        on_alarm = callbacks(supervisor)["/fiper/alarm"]
        for rollout_id in range(1, 3 * HALTED_MEMORY):
            on_alarm(FailureAlarm(rollout_id=rollout_id, state=FailureAlarm.STATE_ALARM))
        assert len(supervisor.halts) == HALTED_MEMORY and supervisor.halts[-1].rollout_id == 3 * HALTED_MEMORY - 1
    finally:
        supervisor.destroy_node()
