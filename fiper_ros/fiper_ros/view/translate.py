"""ROS 2 messages as Foxglove reads them, without rclpy: JSON for the suite's messages and the diagnostics,
``foxglove.RawImage`` for camera images.

A message becomes a dict field for field, under the names of its ``.msg`` definition, as Foxglove shows the
same message read from a bag, so that one layout serves the live view and the bags (``fiper record``, the
demo's): nested messages are objects, arrays are lists, a ``builtin_interfaces/Time`` or ``Duration`` is
``{"sec", "nsec"}`` (Foxglove's name for ROS 2's ``nanosec``), a byte (``octet``) is a number, and a float
that is NaN or infinite is ``null`` (JSON has no such number; a NaN threshold means "not calibrated").

The JSON Schema of a message type (:func:`json_schema`) is made from the same field types, so a message and
its schema cannot disagree. Only the message class's own description is read (``get_fields_and_field_types``,
as every ``rosidl`` generated Python class has it); nested types are imported by name.
"""
from __future__ import annotations

import math
import re
from typing import Any

from foxglove.messages import RawImage, Timestamp

from fiper_ros.interface.messages import message_class

#: ``builtin_interfaces`` types that are times: ``{"sec", "nsec"}`` in Foxglove.
TIME_TYPES = frozenset({"builtin_interfaces/Time", "builtin_interfaces/Duration"})
INTEGER_TYPES = frozenset({"octet", "char", "byte", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64",
                           "uint64"})
FLOAT_TYPES = frozenset({"float", "double", "float32", "float64"})
#: ``sequence<T>``, ``sequence<T, N>`` (bounded) and ``T[N]`` (fixed size): the element type T.
_ARRAY = re.compile(r"^sequence<([^,>]+)(?:, *\d+)?>$|^(.+)\[\d*\]$")


def type_name(cls: type) -> str:
    """``pkg/msg/Name`` of a generated message class (the schema name Foxglove matches panels by)."""
    return f"{cls.__module__.split('.')[0]}/msg/{cls.__name__}"


def _element(kind: str) -> str | None:
    """The element type of an array field type, or None for a field that is not an array."""
    match = _ARRAY.match(kind)
    return None if match is None else (match.group(1) or match.group(2)).strip()


def _nested(kind: str) -> type:
    """The class of a nested field type ``pkg/Name``."""
    package, _, name = kind.rpartition("/")
    return message_class(f"{package}/msg/{name}")


def finite_or_none(value: float) -> float | None:
    """``value`` as a float, ``None`` if NaN or infinite."""
    number = float(value)
    return number if math.isfinite(number) else None


def _value(kind: str, value: Any) -> Any:
    element = _element(kind)
    if element is not None:
        return [_value(element, item) for item in value]
    if kind in TIME_TYPES:
        return {"sec": int(value.sec), "nsec": int(value.nanosec)}
    if "/" in kind:
        return to_json(value)
    if kind in FLOAT_TYPES:
        return finite_or_none(value)
    if kind in INTEGER_TYPES:
        return value[0] if isinstance(value, bytes) else int(value)
    if kind == "boolean":
        return bool(value)
    return str(value)  # string, wstring, bounded strings


def to_json(msg: Any) -> dict[str, Any]:
    """The message as a JSON-ready dict (see the module's docstring)."""
    return {name: _value(kind, getattr(msg, name)) for name, kind in msg.get_fields_and_field_types().items()}


def _schema(kind: str) -> dict[str, Any]:
    element = _element(kind)
    if element is not None:
        return {"type": "array", "items": _schema(element)}
    if kind in TIME_TYPES:
        return {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
    if "/" in kind:
        return _object_schema(_nested(kind))
    if kind in FLOAT_TYPES:
        return {"type": ["number", "null"]}
    if kind in INTEGER_TYPES:
        return {"type": "integer"}
    return {"type": "boolean" if kind == "boolean" else "string"}


def _object_schema(cls: type) -> dict[str, Any]:
    return {"type": "object",
            "properties": {name: _schema(kind) for name, kind in cls.get_fields_and_field_types().items()}}


def json_schema(cls: type) -> dict[str, Any]:
    """The JSON Schema of :func:`to_json`'s dicts of message class ``cls``, titled with its type name."""
    return {"title": type_name(cls), **_object_schema(cls)}


def raw_image(msg: Any) -> RawImage:
    """A ``sensor_msgs/Image`` as the ``foxglove.RawImage`` Foxglove's Image panel shows (same encodings)."""
    stamp = msg.header.stamp
    return RawImage(timestamp=Timestamp(int(stamp.sec), int(stamp.nanosec)), frame_id=msg.header.frame_id,
                    width=int(msg.width), height=int(msg.height), encoding=msg.encoding, step=int(msg.step),
                    data=bytes(msg.data))
