"""What the live view sends for a message (issue #22): the message field for field as Foxglove shows it from a bag
(times as sec/nsec, bytes as numbers, NaN and infinities as null), valid JSON that its own JSON Schema describes;
by hand and for any message of the types the view serves."""
from __future__ import annotations

import json
import math
from typing import Any

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from foxglove.messages import RawImage, Timestamp
from helpers.fuzz import FLOAT32, STAMP, TEXT, UINT8, UINT32, UINT64
from hypothesis import given, settings
from hypothesis import strategies as st
from sensor_msgs.msg import Image
from std_msgs.msg import Header

from fiper_msgs.msg import FailureAlarm, RolloutEvent, Score
from fiper_ros.view.translate import json_schema, raw_image, to_json, type_name

SERVED = (Score, FailureAlarm, RolloutEvent, DiagnosticArray)


def conforms(value: Any, schema: dict[str, Any]) -> bool:
    """Whether ``value`` is what ``schema`` (the subset :func:`json_schema` writes) describes: every property
    present and of its type (``required`` is implied: a message has every field)."""
    types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]
    checks = {"object": lambda v: isinstance(v, dict) and set(v) == set(schema["properties"])
              and all(conforms(v[k], s) for k, s in schema["properties"].items()),
              "array": lambda v: isinstance(v, list) and all(conforms(i, schema["items"]) for i in v),
              "number": lambda v: isinstance(v, float) and math.isfinite(v),
              "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
              "boolean": lambda v: isinstance(v, bool), "string": lambda v: isinstance(v, str),
              "null": lambda v: v is None}
    return any(checks[t](value) for t in types)


def test_a_score_is_its_fields_with_a_nan_threshold_as_null_and_the_stamp_in_sec_nsec() -> None:
    msg = Score(rollout_id=2**64 - 1, step=7, detector="rnd_oe", score=math.inf, windowed_score=1.5,
                threshold=math.nan, exceeded=True, window=5, complete=False, latency_ms=0.25)
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = 12, 345, "f"
    assert to_json(msg) == {"header": {"stamp": {"sec": 12, "nsec": 345}, "frame_id": "f"}, "rollout_id": 2**64 - 1,
                            "step": 7, "detector": "rnd_oe", "score": None, "windowed_score": 1.5, "threshold": None,
                            "exceeded": True, "window": 5, "complete": False, "latency_ms": 0.25}


def test_an_alarm_keeps_its_state_code_and_reason() -> None:
    msg = FailureAlarm(rollout_id=3, step=4, state=FailureAlarm.STATE_ALARM, latched=True, eta_obs=2.0, gamma_obs=1.0,
                       eta_act=math.nan, gamma_act=-math.inf, combine="", reason="RND-OE 2x threshold since step 4",
                       detectors=["rnd_oe", "progress"], eta=[2.0, math.nan], gamma=[1.0, 0.5],
                       exceeded=[True, False], votes=1)
    out = to_json(msg)
    assert (out["detectors"], out["eta"], out["gamma"], out["exceeded"], out["votes"]) == (
        ["rnd_oe", "progress"], [2.0, None], [1.0, 0.5], [True, False], 1)
    assert (out["state"], out["latched"], out["reason"]) == (1, True, "RND-OE 2x threshold since step 4")
    assert (out["eta_obs"], out["gamma_obs"], out["eta_act"], out["gamma_act"]) == (2.0, 1.0, None, None)


def test_a_diagnostic_array_nests_its_statuses_and_their_byte_level_is_a_number() -> None:
    msg = DiagnosticArray(status=[DiagnosticStatus(level=DiagnosticStatus.ERROR, name="fiper: /fiper/ace_node",
                                                   message="m", hardware_id="/fiper/ace_node",
                                                   values=[KeyValue(key="k", value="v")])])
    assert to_json(msg)["status"] == [{"level": 2, "name": "fiper: /fiper/ace_node", "message": "m",
                                       "hardware_id": "/fiper/ace_node", "values": [{"key": "k", "value": "v"}]}]


def test_each_schema_is_titled_with_its_type_and_names_every_field() -> None:
    for cls in SERVED:
        schema = json_schema(cls)
        assert schema["title"] == type_name(cls) == f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"
        assert list(schema["properties"]) == list(cls.get_fields_and_field_types())
    score = json_schema(Score)["properties"]
    assert score["threshold"] == {"type": ["number", "null"]} and score["step"] == {"type": "integer"}
    assert score["header"]["properties"]["stamp"]["properties"] == {"sec": {"type": "integer"},
                                                                    "nsec": {"type": "integer"}}
    status = json_schema(DiagnosticArray)["properties"]["status"]
    assert status["type"] == "array" and status["items"]["properties"]["level"] == {"type": "integer"}
    assert type_name(Image) == "sensor_msgs/msg/Image"


def _header(draw: st.DrawFn) -> Header:
    return Header(stamp=draw(STAMP), frame_id=draw(TEXT))


@st.composite
def messages(draw: st.DrawFn) -> Any:
    """Any message of a type the view serves as JSON, its numbers at their extremes."""
    kind = draw(st.sampled_from(SERVED))
    if kind is Score:
        return Score(header=_header(draw), rollout_id=draw(UINT64), step=draw(UINT32), detector=draw(TEXT),
                     score=draw(FLOAT32), windowed_score=draw(FLOAT32), threshold=draw(FLOAT32),
                     exceeded=draw(st.booleans()), window=draw(UINT32), complete=draw(st.booleans()),
                     latency_ms=draw(FLOAT32))
    if kind is FailureAlarm:
        return FailureAlarm(header=_header(draw), rollout_id=draw(UINT64), step=draw(UINT32), state=draw(UINT8),
                            latched=draw(st.booleans()), eta_obs=draw(FLOAT32), gamma_obs=draw(FLOAT32),
                            eta_act=draw(FLOAT32), gamma_act=draw(FLOAT32), combine=draw(TEXT), reason=draw(TEXT),
                            heartbeat=draw(st.booleans()))
    if kind is RolloutEvent:
        return RolloutEvent(header=_header(draw), rollout_id=draw(UINT64), event=draw(UINT8), outcome=draw(UINT8),
                            task=draw(TEXT), scenario=draw(TEXT), max_steps=draw(UINT32))
    statuses = [DiagnosticStatus(level=bytes([draw(UINT8)]), name=draw(TEXT), message=draw(TEXT),
                                 hardware_id=draw(TEXT),
                                 values=[KeyValue(key=draw(TEXT), value=draw(TEXT))
                                         for _ in range(draw(st.integers(0, 3)))])
                for _ in range(draw(st.integers(0, 3)))]
    return DiagnosticArray(header=_header(draw), status=statuses)


@settings(max_examples=300, deadline=None, derandomize=True, database=None)
@given(messages())
def test_any_served_message_is_valid_json_its_schema_describes_and_keeps_every_finite_number(msg: Any) -> None:
    out = to_json(msg)
    assert conforms(out, json_schema(type(msg)))
    assert json.loads(json.dumps(out, allow_nan=False)) == out  # strict JSON: no NaN or Infinity tokens
    for name, kind in msg.get_fields_and_field_types().items():
        value = getattr(msg, name)
        if kind == "float":
            assert out[name] == (value if math.isfinite(value) else None), name
        elif kind in ("uint8", "uint32", "uint64", "string", "boolean"):
            assert out[name] == value, name
    assert out["header"]["stamp"] == {"sec": msg.header.stamp.sec, "nsec": msg.header.stamp.nanosec}


def test_an_image_becomes_the_raw_image_of_the_same_fields() -> None:
    msg = Image(height=2, width=3, encoding="rgb8", is_bigendian=0, step=9, data=bytes(range(18)))
    msg.header.stamp.sec, msg.header.stamp.nanosec, msg.header.frame_id = 5, 6, "wrist"
    expected = RawImage(timestamp=Timestamp(5, 6), frame_id="wrist", width=3, height=2, encoding="rgb8", step=9,
                        data=bytes(range(18)))
    assert raw_image(msg).encode() == expected.encode()
    assert raw_image(msg).encode() != RawImage(timestamp=Timestamp(5, 6), frame_id="wrist", width=2, height=3,
                                               encoding="rgb8", step=9, data=bytes(range(18))).encode()
