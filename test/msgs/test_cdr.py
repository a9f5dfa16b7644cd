"""The wire codec (``fiper_ros.interface.cdr``, issue #24) against rclpy's own serialization: every message the suite
reads or writes as bytes decodes to the message rclpy builds from the same bytes, and encodes to bytes rclpy reads
back as the same message; bytes that are no such message are a ``CdrError``, never another exception."""
from __future__ import annotations

import math
import struct
from typing import Any

import numpy as np
import pytest
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from hypothesis import given, settings
from hypothesis import strategies as st
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Header

from fiper_msgs.msg import ActionChunkBatch, FailureAlarm, ObservationEmbedding, RolloutEvent, Score, StepSignals
from fiper_ros.bagio.schema import message_cdr
from fiper_ros.interface.cdr import CDR_LE, CdrError, EncapsulationError, codec
from fiper_ros.interface.conversions import (STAMP_MAX_NS, STAMP_MIN_NS, header_view, signals_of, step_signals_cdr,
                                             step_signals_msg, to_stamp)
from helpers.samples import as_plain, sample_messages

PROPERTY = settings(max_examples=150, deadline=None, derandomize=True, database=None)
UINT32, UINT64 = st.integers(0, 2**32 - 1), st.integers(0, 2**64 - 1)
INT32 = st.integers(-(2**31), 2**31 - 1)
#: Any float a float32 field may be given: NaN, infinities, beyond float32 (written as an infinity), tiny.
FLOAT = st.one_of(st.sampled_from([math.nan, math.inf, -math.inf, 3.5e38, -1e300, 1e-45, -0.0]), st.floats())
TEXT = st.text(st.characters(blacklist_categories=("Cs",), blacklist_characters="\x00"), max_size=20)
STAMP = st.builds(Time, sec=INT32, nanosec=UINT32)
HEADER = st.builds(Header, stamp=STAMP, frame_id=TEXT)
FLOATS32 = st.lists(st.floats(width=32, allow_nan=False), max_size=40).map(lambda v: np.asarray(v, np.float32))

SCORES = st.builds(Score, header=HEADER, rollout_id=UINT64, step=UINT32, detector=TEXT, score=FLOAT,
                   windowed_score=FLOAT, threshold=FLOAT, exceeded=st.booleans(), window=UINT32,
                   complete=st.booleans(), latency_ms=FLOAT)
ALARMS = st.builds(FailureAlarm, header=HEADER, rollout_id=UINT64, step=UINT32, state=st.integers(0, 255),
                   latched=st.booleans(), obs_exceeded=st.booleans(), act_exceeded=st.booleans(), eta_obs=FLOAT,
                   gamma_obs=FLOAT, eta_act=FLOAT, gamma_act=FLOAT, combine=TEXT, reason=TEXT, heartbeat=st.booleans())
EMBEDDINGS = st.builds(ObservationEmbedding, header=HEADER, rollout_id=UINT64, step=UINT32, data=FLOATS32,
                       shape=st.lists(UINT32, max_size=4))
BATCHES = st.builds(ActionChunkBatch, header=HEADER, rollout_id=UINT64, step=UINT32, batch_size=UINT32, horizon=UINT32,
                    action_dim=UINT32, exec_steps=UINT32, action_space=TEXT, data=FLOATS32)
SIGNALS = st.builds(StepSignals, header=HEADER, rollout_id=UINT64, step=UINT32, names=st.lists(TEXT, max_size=5),
                    values=st.lists(st.floats(), max_size=5))
DIAGNOSTICS = st.builds(DiagnosticArray, header=HEADER, status=st.lists(st.builds(
    DiagnosticStatus, level=st.binary(min_size=1, max_size=1), name=TEXT, message=TEXT, hardware_id=TEXT,
    values=st.lists(st.builds(KeyValue, key=TEXT, value=TEXT), max_size=5)), max_size=3))
JOINT_STATES = st.builds(JointState, header=HEADER, name=st.lists(TEXT, max_size=4),
                         position=st.lists(st.floats(), max_size=4), velocity=st.lists(st.floats(), max_size=4),
                         effort=st.lists(st.floats(), max_size=4))


def plain(value: Any) -> Any:
    """A message or a codec view as nested plain data, numbers by their bits (NaN equals NaN), any sequence of
    numbers as its float64 values (rclpy: ``array.array`` or list; the codec: a numpy array)."""
    if hasattr(value, "_fields"):
        return {name: plain(getattr(value, name)) for name in value._fields}
    if hasattr(value, "get_fields_and_field_types"):
        return {name: plain(getattr(value, name)) for name in value.get_fields_and_field_types()}
    if isinstance(value, str | bytes | bool | int):
        return value
    if isinstance(value, float):
        return np.float64(value).tobytes()
    items = list(value)
    if items and not hasattr(items[0], "_fields") and not hasattr(items[0], "get_fields_and_field_types") \
            and not isinstance(items[0], str):
        return np.asarray(items, dtype=np.float64).tobytes()
    return [plain(item) for item in items]


def through_rclpy(msg: Any) -> Any:
    """``msg`` as it arrives: serialized and deserialized by rclpy (float32 fields rounded as the C cast does)."""
    return deserialize_message(serialize_message(msg), type(msg))


def check(msg: Any) -> None:
    wire = codec(type(msg))
    arrived = through_rclpy(msg)
    view = wire.decode(serialize_message(msg))
    assert plain(view) == plain(arrived)
    encoded = wire.encode(msg)
    assert plain(deserialize_message(encoded, type(msg))) == plain(arrived)
    assert wire.encode(view) == encoded  # a view writes the bytes its message writes


@pytest.mark.parametrize("name", sorted(sample_messages()))
def test_every_sample_message_reads_and_writes_as_rclpy_does(name: str) -> None:
    msg = sample_messages()[name]
    check(msg)
    assert as_plain(deserialize_message(codec(type(msg)).encode(msg), type(msg))) == as_plain(msg)


@PROPERTY
@given(st.one_of(SCORES, ALARMS, EMBEDDINGS, BATCHES, SIGNALS, DIAGNOSTICS, JOINT_STATES,
                 st.builds(RolloutEvent, header=HEADER, rollout_id=UINT64, event=st.integers(0, 255),
                           outcome=st.integers(0, 255), task=TEXT, scenario=TEXT, max_steps=UINT32)))
def test_any_message_reads_and_writes_as_rclpy_does(msg: Any) -> None:
    check(msg)


def test_step_signals_bytes_are_the_message_rclpy_and_the_bag_writer_write() -> None:
    signals = {"chunk_mse": 0.125, "eef_z": -1e-300, "action_jerk": 3.5}
    raw = step_signals_cdr(2**64 - 1, 41, 7_000_000_011, signals)
    message = step_signals_msg(2**64 - 1, 41, 7_000_000_011, signals)
    assert plain(deserialize_message(raw, StepSignals)) == plain(message)
    assert raw == message_cdr(message, "fiper_msgs/msg/StepSignals")  # padding zeroed as the bag writer's
    assert signals_of(codec(StepSignals).decode(raw)) == signals
    assert list(signals_of(message)) == ["chunk_mse", "eef_z", "action_jerk"]  # in the order given


def test_a_float32_beyond_its_range_is_written_as_the_infinity_rclpy_writes() -> None:
    msg = Score(windowed_score=1e39, threshold=-1e300, score=3.4028235e38)
    arrived = deserialize_message(codec(Score).encode(msg), Score)
    assert (arrived.windowed_score, arrived.threshold) == (math.inf, -math.inf)
    assert arrived.score == through_rclpy(msg).score  # rounds to the largest float32, not to infinity


def test_numeric_sequences_are_read_only_views_of_the_received_bytes() -> None:
    data = serialize_message(sample_messages()["fiper_msgs/msg/ObservationEmbedding"])
    view = codec(ObservationEmbedding).decode(data)
    assert view.data.dtype == np.float32 and not view.data.flags.writeable and view.data.base is not None
    assert view.shape.dtype == np.uint32 and list(view.shape) == [512]


def test_an_integer_out_of_its_fields_range_is_an_error_not_a_wrapped_value() -> None:
    # rclpy would wrap step 2**32 to 0 without a word; the codec refuses.
    with pytest.raises(CdrError, match="fiper_msgs/msg/Score"):
        codec(Score).encode(codec(Score).view(header=header_view(0), rollout_id=1, step=2**32, detector="ace",
                                              score=0.0, windowed_score=0.0, threshold=0.0, exceeded=False, window=1,
                                              complete=True, latency_ms=0.0))


@pytest.mark.parametrize("name", sorted(sample_messages()))
def test_bytes_that_end_early_are_a_cdr_error(name: str) -> None:
    msg = sample_messages()[name]
    wire = codec(type(msg))
    data = wire.encode(msg)
    ends = sorted({*range(0, min(len(data), 200)), *range(len(data) - 64, len(data))} - {len(data)})
    for end in ends:
        if end < 0:
            continue
        with pytest.raises(CdrError):
            wire.decode(data[:end])


def test_a_length_beyond_the_message_is_a_cdr_error_without_allocating_it() -> None:
    data = bytearray(codec(ObservationEmbedding).encode(sample_messages()["fiper_msgs/msg/ObservationEmbedding"]))
    # body: stamp (8), frame_id (4 + 7 = "policy" + NUL, to 19), pad to 24, rollout_id (8), step (4): data length at 36
    assert struct.unpack_from("<I", data, 4 + 36) == (512,)
    struct.pack_into("<I", data, 4 + 36, 2**32 - 1)
    with pytest.raises(CdrError, match="not such a message"):
        codec(ObservationEmbedding).decode(bytes(data))
    strings = bytearray(codec(DiagnosticArray).encode(DiagnosticArray(status=[DiagnosticStatus()])))
    struct.pack_into("<I", strings, 4 + 16, 2**32 - 1)  # the status count: after the stamp (8), "" (5), padding (3)
    with pytest.raises(CdrError, match="more messages than bytes"):
        codec(DiagnosticArray).decode(bytes(strings))


def test_another_encapsulation_is_named_so_that_rclpy_may_read_it() -> None:
    data = codec(Score).encode(Score(detector="ace"))
    assert data[:4] == CDR_LE
    with pytest.raises(EncapsulationError, match="encapsulation 0000"):
        codec(Score).decode(b"\x00\x00" + data[2:])  # big-endian CDR


def test_a_header_holds_the_nearest_stamp_a_time_can_hold() -> None:
    # the typed stamp follows the same rule (the generated class refused a time beyond int32 seconds)
    assert (to_stamp(STAMP_MAX_NS + 10**12).sec, to_stamp(STAMP_MAX_NS + 10**12).nanosec) == (2**31 - 1, 999_999_999)
    assert (to_stamp(STAMP_MIN_NS - 1).sec, to_stamp(STAMP_MIN_NS - 1).nanosec) == (-(2**31), 0)
    assert header_view(STAMP_MAX_NS + 10**12).stamp == (2**31 - 1, 999_999_999)
    assert header_view(STAMP_MIN_NS - 1).stamp == (-(2**31), 0)
    assert header_view(1_500_000_000).stamp == (1, 500_000_000)
    assert header_view(-1).stamp == (-1, 999_999_999)
    assert plain(deserialize_message(codec(Header).encode(header_view(-1, "x")), Header)) == plain(
        Header(stamp=Time(sec=-1, nanosec=999_999_999), frame_id="x"))
