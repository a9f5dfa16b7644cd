"""Rollout signals in bags (``/fiper/step_signals``, one StepSignals message per step): written by ``write_rollouts``
and read back into ``Rollout.signals`` bit for bit; a rollout whose steps name different signals, or a step without
its signals, is refused in one line naming the bag, rollout and step; a recording cut inside a step's messages loses
that step only."""
from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from fiper_msgs.msg import RolloutEvent, StepSignals
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import read_rollouts, write_rollouts
from fiper_ros.bagio.schema import BagInfo, message_cdr
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.core.rollout import Rollout
from fiper_ros.interface.conversions import embedding_msg, rollout_event_msg, step_signals_msg
from fiper_ros.interface.topics import EMBEDDING_TOPIC, EVENTS_TOPIC, STEP_SIGNALS_TOPIC, TOPICS


def _rollout(name: str, steps: int, signals: dict[str, np.ndarray]) -> Rollout:
    rng = np.random.default_rng(steps)
    return Rollout(name, "pick", "id", rng.normal(size=(steps, 3)), rng.normal(size=(steps, 2, 4, 2)), 2, True,
                   signals=signals)


def test_signals_round_trip_bit_for_bit(tmp_path: Path) -> None:
    values = np.array([1e-300, -0.0, np.pi, 1.7976931348623157e308])
    rollouts = [_rollout("a", 4, {"chunk_mse": values, "eef_z": values[::-1].copy()}), _rollout("b", 2, {})]
    write_rollouts(tmp_path / "bag", rollouts, [3, 4], BagInfo())
    with BagReader(tmp_path / "bag") as reader:
        assert reader.offered_qos(STEP_SIGNALS_TOPIC)[0].durability.name == "VOLATILE"
        messages = [reader.decode(m) for m in reader.messages([STEP_SIGNALS_TOPIC])]
    assert [(m.rollout_id, m.step) for m in messages] == [(3, 0), (3, 1), (3, 2), (3, 3)]  # none for rollout b
    first, plain = read_rollouts(tmp_path / "bag")
    assert list(first.signals) == ["chunk_mse", "eef_z"] and plain.signals == {}
    assert first.signals["chunk_mse"].tobytes() == values.tobytes()
    assert first.signals["eef_z"].tobytes() == values[::-1].tobytes()


def _bag(path: Path, steps: list[dict[str, float] | None], *, end: bool = True,
         embedded: int | None = None) -> Path:
    """A bag of rollout 7 by hand: START, per step an embedding (the first ``embedded`` steps; all by default) and
    the given signals (None: no StepSignals message), END if ``end``."""
    with BagWriter(path) as writer:
        writer.info = BagInfo(task="pick")

        def put(topic: str, stamp: int, msg: object) -> None:
            writer.write(topic, stamp, message_cdr(msg, TOPICS[topic].msgtype))

        put(EVENTS_TOPIC, 1, rollout_event_msg(7, RolloutEvent.EVENT_START, 1, task="pick"))
        for step, signals in enumerate(steps):
            stamp = 10 + step
            if embedded is None or step < embedded:
                put(EMBEDDING_TOPIC, stamp, embedding_msg(7, step, stamp, np.full(2, step, np.float32)))
            if signals is not None:
                put(STEP_SIGNALS_TOPIC, stamp, step_signals_msg(7, step, stamp, signals))
        if end:
            put(EVENTS_TOPIC, 99, rollout_event_msg(7, RolloutEvent.EVENT_END, 99,
                                                    outcome=RolloutEvent.OUTCOME_SUCCESS))
    return path


def test_signals_read_back_by_name_whatever_their_order_at_a_step(tmp_path: Path) -> None:
    (rollout,) = read_rollouts(_bag(tmp_path / "bag", [{"a": 1.0, "b": 2.0}, {"b": 4.0, "a": 3.0}]))
    assert {k: v.tolist() for k, v in rollout.signals.items()} == {"a": [1.0, 3.0], "b": [2.0, 4.0]}


@pytest.mark.parametrize(("steps", "message"), [
    ([{"a": 1.0}, {"b": 2.0}], "rollout 7 step 1: step signals name b, step 0 a: every step of a rollout names the "
                               "same signals"),
    ([{"a": 1.0}, {"a": 1.0, "b": 2.0}], "rollout 7 step 1: step signals name a, b, step 0 a: "),
    ([{"a": 1.0}, None, {"a": 3.0}], r"rollout 7 has no step signals message for step 1 \(steps 0..2 present\)"),
    ([{"a": 1.0}, {"a": np.nan}], "rollout 7: rollout '7': signal 'a' is NaN/inf at step 1"),
    ([{"Bad": 1.0}], "rollout 7: rollout '7': signal name 'Bad' must match"),
])
def test_steps_that_disagree_are_refused_naming_bag_rollout_and_step(tmp_path: Path, steps: list, message: str) -> None:
    bag = _bag(tmp_path / "bag", steps)
    with pytest.raises(BagError, match=f"^{bag}: {message}"):
        read_rollouts(bag)


def _embedding() -> bytes:
    return message_cdr(embedding_msg(7, 0, 10, np.zeros(2, np.float32)), TOPICS[EMBEDDING_TOPIC].msgtype)


def test_a_signals_message_of_more_names_than_values_is_refused(tmp_path: Path) -> None:
    bag = tmp_path / "bag"
    with BagWriter(bag) as writer:
        msg = StepSignals(rollout_id=7, step=0, names=["a", "b"], values=[1.0])
        writer.write(EMBEDDING_TOPIC, 10, _embedding())
        writer.write(STEP_SIGNALS_TOPIC, 10, message_cdr(msg, TOPICS[STEP_SIGNALS_TOPIC].msgtype))
    with pytest.raises(BagError, match=f"^{bag}: rollout 7 step 0: step signals: 2 signal names but 1 values$"):
        read_rollouts(bag)
    with BagWriter(bag, overwrite=True) as writer:
        msg = StepSignals(rollout_id=7, step=0, names=["a", "a"], values=[1.0, 2.0])
        writer.write(STEP_SIGNALS_TOPIC, 10, message_cdr(msg, TOPICS[STEP_SIGNALS_TOPIC].msgtype))
        writer.write(EMBEDDING_TOPIC, 10, _embedding())
    with pytest.raises(BagError, match=r"rollout 7 step 0: step signals: a signal name repeats \(a, a\)$"):
        read_rollouts(bag)


def test_a_recording_cut_inside_a_steps_messages_loses_that_step(tmp_path: Path,
                                                                 caplog: pytest.LogCaptureFixture) -> None:
    """No END (the recording stopped): the last step's embedding arrived but not its signals, or the reverse."""
    with caplog.at_level(logging.WARNING):
        (rollout,) = read_rollouts(_bag(tmp_path / "a", [{"a": 1.0}, {"a": 2.0}, None], end=False))
    assert rollout.length == 2 and rollout.signals["a"].tolist() == [1.0, 2.0] and rollout.success is None
    assert "rollout 7 ends inside step 2 (only its observation embedding, no END): that step is left out" in caplog.text
    (rollout,) = read_rollouts(_bag(tmp_path / "b", [{"a": 1.0}, {"a": 2.0}], end=False, embedded=1))
    assert rollout.length == 1 and rollout.signals["a"].tolist() == [1.0]
    assert "ends inside step 1 (only its step signals message, no END)" in caplog.text
    with pytest.raises(BagError, match="rollout 7 has no step signals message for step 2"):  # with END: refused
        read_rollouts(_bag(tmp_path / "c", [{"a": 1.0}, {"a": 2.0}, None]))
