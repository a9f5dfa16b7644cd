"""Message <-> array conversions, kept cheap: no per-element Python work on large arrays."""
from __future__ import annotations

import array
from collections.abc import Mapping
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from std_msgs.msg import Header

from fiper_msgs.msg import ActionChunkBatch, ActionCommand, ObservationEmbedding, RolloutEvent, StepSignals
from fiper_ros.interface.cdr import codec

_TIME_VIEW = codec(Time).view
_HEADER_VIEW = codec(Header).view
_EMBEDDING = codec(ObservationEmbedding)
_BATCH = codec(ActionChunkBatch)
_SIGNALS = codec(StepSignals)


def float_array(values: np.ndarray) -> array.array:
    """A float32 numpy array as the ``array.array`` rclpy stores in ``float32[]`` fields (fast path)."""
    return array.array("f", np.ascontiguousarray(values, dtype=np.float32).tobytes())


def floats_of(field: array.array | list[float]) -> np.ndarray:
    """A ``float32[]`` field as a numpy array without copying when possible."""
    if isinstance(field, array.array):
        return np.frombuffer(field, dtype=np.float32) if len(field) else np.zeros(0, np.float32)
    return np.asarray(field, dtype=np.float32)


def stamp_ns(stamp: Time) -> int:
    """A message stamp in nanoseconds."""
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


#: The earliest and the latest time a ``builtin_interfaces/Time`` holds (``sec`` is an int32), in nanoseconds.
STAMP_MIN_NS, STAMP_MAX_NS = -(2**31) * 1_000_000_000, (2**31 - 1) * 1_000_000_000 + 999_999_999


def stamp_fields(ns: int) -> tuple[int, int]:
    """Nanoseconds as a stamp's ``(sec, nanosec)``. A time beyond what the stamp holds is the nearest it holds (a
    sum of stamps whose ``nanosec`` is beyond a second can be): rclpy would wrap it into a time of another century,
    or the generated class refuse it."""
    ns = min(max(int(ns), STAMP_MIN_NS), STAMP_MAX_NS)
    return ns // 1_000_000_000, ns % 1_000_000_000


def to_stamp(ns: int) -> Time:
    """Nanoseconds as a message stamp (:func:`stamp_fields`)."""
    sec, nanosec = stamp_fields(ns)
    return Time(sec=sec, nanosec=nanosec)


def header_view(ns: int, frame_id: str = "") -> Any:
    """A ``std_msgs/Header`` stamped ``ns`` (:func:`stamp_fields`) as the wire codec writes it
    (:mod:`fiper_ros.interface.cdr`)."""
    return _HEADER_VIEW(_TIME_VIEW(*stamp_fields(ns)), frame_id)


def embedding_msg(rollout_id: int, step: int, stamp: int, embedding: np.ndarray) -> ObservationEmbedding:
    """An ObservationEmbedding of a flat or shaped embedding array."""
    msg = ObservationEmbedding(rollout_id=rollout_id, step=step, data=float_array(embedding.ravel()),
                               shape=list(np.shape(embedding)))
    msg.header.stamp = to_stamp(stamp)
    return msg


def action_batch_msg(rollout_id: int, step: int, stamp: int, actions: np.ndarray, exec_steps: int,
                     action_space: str) -> ActionChunkBatch:
    """An ActionChunkBatch of a ``[B, H, D]`` array."""
    b, h, d = actions.shape
    msg = ActionChunkBatch(rollout_id=rollout_id, step=step, batch_size=b, horizon=h, action_dim=d,
                           exec_steps=exec_steps, data=float_array(actions), action_space=action_space)
    msg.header.stamp = to_stamp(stamp)
    return msg


def embedding_cdr(rollout_id: int, step: int, stamp: int, embedding: np.ndarray) -> bytes:
    """:func:`embedding_msg`'s message as the bytes a publisher takes (:mod:`fiper_ros.interface.cdr`): what a
    policy publishes every step, without the generated class's per-field Python work."""
    values = np.asarray(embedding, dtype=np.float32)
    return _EMBEDDING.encode(_EMBEDDING.view(header=header_view(stamp), rollout_id=rollout_id, step=step,
                                             data=values.ravel(), shape=values.shape))


def action_batch_cdr(rollout_id: int, step: int, stamp: int, actions: np.ndarray, exec_steps: int,
                     action_space: str) -> bytes:
    """:func:`action_batch_msg`'s message as the bytes a publisher takes (see :func:`embedding_cdr`)."""
    actions = np.asarray(actions, dtype=np.float32)
    b, h, d = actions.shape
    return _BATCH.encode(_BATCH.view(header=header_view(stamp), rollout_id=rollout_id, step=step, batch_size=b,
                                     horizon=h, action_dim=d, exec_steps=exec_steps, action_space=action_space,
                                     data=actions.ravel()))


def step_signals_msg(rollout_id: int, step: int, stamp: int, signals: Mapping[str, float]) -> StepSignals:
    """A StepSignals of named per-step values (in the mapping's order)."""
    msg = StepSignals(rollout_id=rollout_id, step=step, names=list(signals),
                      values=array.array("d", np.asarray(list(signals.values()), dtype=np.float64).tobytes()))
    msg.header.stamp = to_stamp(stamp)
    return msg


def step_signals_cdr(rollout_id: int, step: int, stamp: int, signals: Mapping[str, float]) -> bytes:
    """:func:`step_signals_msg`'s message as the bytes a publisher takes (see :func:`embedding_cdr`)."""
    return _SIGNALS.encode(_SIGNALS.view(header=header_view(stamp), rollout_id=rollout_id, step=step,
                                         names=list(signals),
                                         values=np.asarray(list(signals.values()), dtype=np.float64)))


def signals_of(msg: Any) -> dict[str, float]:  # a StepSignals message or view
    """A StepSignals message (or its wire view) as ``{name: value}``; :class:`ValueError` if names and values
    differ in number or a name repeats."""
    names, values = list(msg.names), np.asarray(msg.values, dtype=np.float64)
    if len(names) != values.size:
        raise ValueError(f"{len(names)} signal names but {values.size} values")
    if len(set(names)) != len(names):
        raise ValueError(f"a signal name repeats ({', '.join(names)})")
    return dict(zip(names, values.tolist(), strict=True))


def action_command_msg(rollout_id: int, step: int, stamp: int, actions: np.ndarray, action_space: str,
                       observation_history: int) -> ActionCommand:
    """An ActionCommand of the ``[n, D]`` actions to execute (``observation_history``: the control-step
    observations wanted before the next tick)."""
    n, d = actions.shape
    msg = ActionCommand(rollout_id=rollout_id, step=step, num_actions=n, action_dim=d, data=float_array(actions),
                        action_space=action_space, observation_history=observation_history)
    msg.header.stamp = to_stamp(stamp)
    return msg


def rollout_event_msg(rollout_id: int, event: int, stamp: int, *, outcome: int = 0, task: str = "",
                      scenario: str = "", max_steps: int = 0) -> RolloutEvent:
    """A RolloutEvent (START = 0, END = 1; outcome UNKNOWN = 0, SUCCESS = 1, FAILURE = 2)."""
    msg = RolloutEvent(rollout_id=rollout_id, event=event, outcome=outcome, task=task, scenario=scenario,
                       max_steps=max_steps)
    msg.header.stamp = to_stamp(stamp)
    return msg
