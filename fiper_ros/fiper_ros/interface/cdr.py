"""The suite's messages as CDR bytes, read and written without rclpy's Python message classes.

rclpy turns every message it takes into an object of the generated class (a Python ``__init__`` and one property
setter per field, a nested object per header and stamp, an ``array.array`` copy of every ``float32[]``) and every
message it publishes back into C. For a process that relays an embedding into a Score that was about a third of
its CPU per message at 1000 messages/s (docs/benchmarks.md, "Wire codec"). The nodes therefore subscribe to
their hot inputs raw (``raw=True``: the CDR bytes) and publish bytes, and this module reads and writes them.

A :class:`Codec` is compiled once per message type from the generated class's own description
(``get_fields_and_field_types`` and ``SLOT_TYPES``, which rosidl writes from the ``.msg`` file), so it follows the
message definitions. :meth:`Codec.decode` gives a *view*: a named tuple per message (nested messages nested),
with the field names of the generated class, so code that reads ``msg.header.stamp.sec`` or ``msg.data`` reads a
view and an rclpy message alike; numeric sequences and arrays are read-only numpy arrays over the received bytes
(no copy). :meth:`Codec.encode` reads the fields by attribute from a view or an rclpy message and writes the
message ``rclpy.serialization.serialize_message`` writes (rclpy reads both back equal), padding zeroed and no
bytes after the last field (rclpy leaves padding uninitialised and may add some).

The wire format is plain CDR, little endian (encapsulation ``CDR_LE``, what the ROS 2 middlewares write for these
types): each primitive aligned to its size (at most 8) from the start of the body after the 4-byte encapsulation
header; a string is its length with the terminating NUL (uint32), its UTF-8 bytes and the NUL; a sequence its
length (uint32) and its elements; a fixed array its elements. Anything else (another encapsulation, bytes that end
early, a length that does not fit the message) is a :class:`CdrError`: the caller falls back to rclpy or rejects
the message, and no length read from the bytes sizes work beyond the bytes themselves.

Differences from the generated classes, by design: a view is immutable; a numeric sequence is a numpy array
(rclpy: ``array.array``); ``float32`` values that do not fit are written as infinities (the C cast rclpy uses);
an integer out of its field's range is an error (rclpy would wrap it).
"""
from __future__ import annotations

import importlib
import math
import struct
import textwrap
from collections import namedtuple
from collections.abc import Callable
from typing import Any

import numpy as np

from fiper_ros.errors import FiperError

__all__ = ["CDR_LE", "CdrError", "Codec", "EncapsulationError", "codec"]

#: The encapsulation header of little-endian plain CDR (the first 4 bytes of every serialized message).
CDR_LE = b"\x00\x01\x00\x00"
#: rosidl basic types: struct code (little endian), size in bytes (= alignment).
_BASIC = {
    "boolean": ("?", 1), "octet": ("c", 1), "int8": ("b", 1), "uint8": ("B", 1), "int16": ("h", 2), "uint16": ("H", 2),
    "int32": ("i", 4), "uint32": ("I", 4), "int64": ("q", 8), "uint64": ("Q", 8), "float": ("f", 4),
    "double": ("d", 8),
}
#: numpy dtypes of the basic types a numeric sequence or array may hold.
_DTYPES = {"boolean": "?", "int8": "i1", "uint8": "u1", "int16": "<i2", "uint16": "<u2", "int32": "<i4",
           "uint32": "<u4", "int64": "<i8", "uint64": "<u8", "float": "<f4", "double": "<f8"}
_U32 = struct.Struct("<I")
_ZEROS = bytes(8)
_FLOAT32_MAX = float(np.finfo(np.float32).max)


class CdrError(FiperError):
    """Bytes that are not a message of the codec's type in plain little-endian CDR."""


class EncapsulationError(CdrError):
    """Bytes of another encapsulation than plain little-endian CDR (which rclpy's deserializer may read)."""


def _float32(value: float) -> float:
    """``value`` as C's cast to float32 gives it: an infinity where it does not fit (``struct`` raises there)."""
    value = float(value)
    if math.isfinite(value) and abs(value) > _FLOAT32_MAX:
        with np.errstate(over="ignore"):
            return float(np.float32(value))
    return value


def _pad(size: int) -> str:
    """Encoder lines: zero bytes up to the next multiple of ``size`` (a power of two) from the body's start."""
    return f"p = -o & {size - 1}\nif p: parts.append(Z[:p]); o += p"


def _read_string(target: str) -> str:
    """Decoder lines: a string (uint32 length with its NUL, the bytes, the NUL) into ``target``."""
    return ("o += -o & 3\nm, = U.unpack_from(b, o); o += 4\n"
            "if m > len(b) - o: raise CdrError('string longer than the message')\n"
            f"{target} = str(b[o:o + m - 1], 'utf-8', 'replace') if m else ''; o += m")


def _write_string(value: str) -> str:
    """Encoder lines: the string ``value`` (an expression)."""
    return (f"{_pad(4)}\ne = {value}.encode()\n"
            "parts.append(U.pack(len(e) + 1)); parts.append(e); parts.append(Z[:1]); o += 5 + len(e)")


def _block(header: str, body: str) -> str:
    """``body`` (lines) under the compound statement ``header``."""
    return f"{header}\n{textwrap.indent(body, '    ')}"


class _Source:
    """Python source of one message type's decode and encode functions, written field by field."""

    def __init__(self, key: str, env: dict[str, Any]) -> None:
        self.key = key
        self.env = env  # the functions' globals: the compiled structs go there
        self.dec: list[str] = []
        self.enc: list[str] = []
        self.run: list[tuple[str, str]] = []  # (field, rosidl type) of the pending fixed run
        self.run_fmt = ""
        self.align = 1  # what is known of the offset here: a multiple of ``align`` plus ``rem``
        self.rem = 0
        self.runs = 0  # fixed runs written so far (each a struct of its own)

    def basic(self, field: str, typename: str) -> None:
        code, size = _BASIC[typename]
        if size > self.align:  # alignment not known statically: end the run, align at run time
            self.flush()
            self.dec.append(f"o += -o & {size - 1}")
            self.enc.append(_pad(size))
            self.align, self.rem = size, 0
        pad = -self.rem & (size - 1)
        self.run_fmt += "x" * pad + code
        self.run.append((field, typename))
        self.rem = (self.rem + pad + size) % self.align

    def flush(self) -> None:
        """Write the pending fixed run as one ``struct`` call."""
        if not self.run:
            return
        fmt = struct.Struct("<" + self.run_fmt)
        const = f"S_{self.key}_{self.runs}"
        self.runs += 1
        self.env[const] = fmt
        names = [f"v_{field}" for field, _ in self.run]
        self.dec.append(f"{', '.join(names)}, = {const}.unpack_from(b, o); o += {fmt.size}")
        values = [f"F(v.{field})" if typename == "float" else f"v.{field}" for field, typename in self.run]
        self.enc.append(f"parts.append({const}.pack({', '.join(values)})); o += {fmt.size}")
        self.run, self.run_fmt = [], ""

    def unknown(self) -> None:
        """A variable-length field was written: nothing is known of the offset after it."""
        self.align, self.rem = 1, 0


class Codec:
    """Decode and encode one message type's plain little-endian CDR (see the module docstring)."""

    def __init__(self, msg_class: type) -> None:
        self.msg_class = msg_class
        self.type_name = _type_name(msg_class)
        env: dict[str, Any] = {"U": _U32, "Z": _ZEROS, "F": _float32, "CdrError": CdrError, "np": np,
                               "PACK": struct.pack, "PACK_ERRORS": (struct.error, OverflowError)}
        self._compile(msg_class, env)
        key = _key(msg_class)
        self.view: type = env[f"V_{key}"]
        """The named tuple of a decoded message (nested messages are named tuples of their own type)."""
        self._decode: Callable[[memoryview, int], tuple[Any, int]] = env[f"dec_{key}"]
        self._encode: Callable[[Any, list[Any], int], int] = env[f"enc_{key}"]

    def decode(self, data: bytes) -> Any:
        """The view of ``data`` (serialized bytes of this type); :class:`CdrError` if they are not."""
        if data[:2] != CDR_LE[:2]:
            raise EncapsulationError(f"{self.type_name}: encapsulation {bytes(data[:2]).hex()} is not plain "
                                     "little-endian CDR")
        try:
            view, _ = self._decode(memoryview(data)[4:], 0)
        except (struct.error, ValueError, IndexError) as error:
            raise CdrError(f"{self.type_name}: {len(data)} bytes that are not such a message ({error})") from error
        return view

    def encode(self, message: Any) -> bytes:
        """The serialized bytes of ``message`` (a view of this type, or an object with its fields as attributes)."""
        parts: list[Any] = [CDR_LE]
        try:
            self._encode(message, parts, 0)
        except struct.error as error:
            raise CdrError(f"{self.type_name}: a value does not fit its field ({error})") from error
        return b"".join(parts)

    # compilation ----------------------------------------------------------------------------------------
    def _compile(self, msg_class: type, env: dict[str, Any]) -> None:
        """Define ``V_<key>``, ``dec_<key>`` and ``enc_<key>`` of ``msg_class`` and of every message it holds."""
        key = _key(msg_class)
        if f"dec_{key}" in env:
            return
        fields = list(msg_class.get_fields_and_field_types())
        env[f"V_{key}"] = namedtuple(msg_class.__name__, fields)  # noqa: PYI024 - a view class per message type
        src = _Source(key, env)
        for name, slot in zip(fields, msg_class.SLOT_TYPES):
            self._field(src, name, slot)
        src.flush()
        values = ", ".join(f"v_{name}" for name in fields)
        code = (_block(f"def dec_{key}(b, o):", "\n".join([*src.dec, f"return V_{key}({values}), o"])) + "\n\n"
                + _block(f"def enc_{key}(v, parts, o):", "\n".join([*src.enc, "return o"])) + "\n")
        exec(compile(code, f"<cdr {self.type_name if msg_class is self.msg_class else key}>", "exec"), env)  # noqa: S102

    def _field(self, src: _Source, name: str, slot: Any) -> None:
        kind = type(slot).__name__
        if kind == "BasicType":
            if slot.typename not in _BASIC:
                raise TypeError(f"{self.type_name}.{name}: type {slot.typename} is not supported")
            src.basic(name, slot.typename)
            return
        src.flush()
        if kind in ("UnboundedString", "BoundedString"):
            src.dec.append(_read_string(f"v_{name}"))
            src.enc.append(_write_string(f"v.{name}"))
        elif kind == "NamespacedType":
            nested = _nested_class(slot)
            self._compile(nested, src.env)
            src.dec.append(f"v_{name}, o = dec_{_key(nested)}(b, o)")
            src.enc.append(f"o = enc_{_key(nested)}(v.{name}, parts, o)")
        elif kind in ("UnboundedSequence", "BoundedSequence", "Array"):
            self._collection(src, name, slot, kind == "Array")
        else:
            raise TypeError(f"{self.type_name}.{name}: {kind} fields are not supported")
        src.unknown()

    def _collection(self, src: _Source, name: str, slot: Any, fixed: bool) -> None:
        """A sequence (length first) or a fixed array of basic values, strings or messages."""
        item = slot.value_type
        item_kind = type(item).__name__
        if fixed:
            src.dec.append(f"n = {slot.size}")
            src.enc.append(f"n = {slot.size}\nif len(v.{name}) != n: raise CdrError('{name}: {slot.size} values "
                           "expected')")
        else:
            src.dec.append("o += -o & 3\nn, = U.unpack_from(b, o); o += 4")
            src.enc.append(f"{_pad(4)}\nn = len(v.{name})\nparts.append(U.pack(n)); o += 4")
        if item_kind == "BasicType" and item.typename in _DTYPES:
            size = _BASIC[item.typename][1]
            dtype = f"D_{src.key}_{name}"
            src.env[dtype] = np.dtype(_DTYPES[item.typename])
            # A sequence's elements follow its uint32 length: only 8-byte ones may need padding (arrays: any).
            realign = size > (1 if fixed else 4)
            read = f"v_{name} = np.frombuffer(b, {dtype}, n, o); o += {size} * n"
            # A list or tuple (what the nodes build per message) is packed by ``struct`` without numpy's per-call
            # cost; what struct refuses (a float beyond float32, a float for an integer) takes numpy's conversion.
            code = _BASIC[item.typename][0]
            write = (f"a = v.{name}\n"
                     + _block("if type(a) is list or type(a) is tuple:",
                              _block("try:", f"e = PACK(f'<{{n}}{code}', *a)")
                              + "\n" + _block("except PACK_ERRORS:", f"e = np.ascontiguousarray(a, {dtype}).tobytes()"))
                     + "\n" + _block("else:", f"e = np.ascontiguousarray(a, {dtype}).tobytes()")
                     + f"\nparts.append(e); o += {size} * n")
            src.dec.append(_block("if n:", f"o += -o & {size - 1}\n{read}" if realign else read)
                           + "\n" + _block("else:", f"v_{name} = np.zeros(0, {dtype})"))
            src.enc.append(_block("if n:", f"{_pad(size)}\n{write}" if realign else write))
            return
        if item_kind in ("UnboundedString", "BoundedString"):
            src.dec.append(f"if n > len(b) - o: raise CdrError('more strings than bytes')\nv_{name} = []\n"
                           + _block("for _ in range(n):", f"{_read_string('s')}\nv_{name}.append(s)"))
            src.enc.append(_block(f"for s in v.{name}:", _write_string("s")))
            return
        if item_kind == "NamespacedType":
            nested = _nested_class(item)
            self._compile(nested, src.env)
            key = _key(nested)
            src.dec.append(f"if n > len(b) - o: raise CdrError('more messages than bytes')\nv_{name} = []\n"
                           + _block("for _ in range(n):", f"x, o = dec_{key}(b, o)\nv_{name}.append(x)"))
            src.enc.append(_block(f"for x in v.{name}:", f"o = enc_{key}(x, parts, o)"))
            return
        raise TypeError(f"{self.type_name}.{name}: sequences of {getattr(item, 'typename', item_kind)} are not "
                        "supported")


def _nested_class(slot: Any) -> type:
    module = importlib.import_module(".".join(slot.namespaces))
    return getattr(module, slot.name)


def _type_name(msg_class: type) -> str:
    package = msg_class.__module__.split(".")[0]
    return f"{package}/msg/{msg_class.__name__}"


def _key(msg_class: type) -> str:
    return f"{msg_class.__module__.split('.')[0]}__{msg_class.__name__}"


_CODECS: dict[type, Codec] = {}


def codec(msg_class: type) -> Codec:
    """The :class:`Codec` of ``msg_class``, compiled at the first call."""
    found = _CODECS.get(msg_class)
    if found is None:
        found = _CODECS[msg_class] = Codec(msg_class)
    return found
