"""Every fiper_msgs type survives an MCAP bag (rosbag2 v9, written with rosbags) bit for bit.

Also: rclpy and rosbags decode each other's CDR to equal values (the bytes differ only in alignment
padding, which rclpy leaves uninitialised), and rosbags' RIHS01 type hashes equal the ones rosidl
generated at build time.
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from rclpy.serialization import deserialize_message, serialize_message
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from helpers.samples import as_plain, sample_messages, topic_of

MSG_DIR = Path(os.environ["FIPER_ROOT"]) / "fiper_msgs" / "msg"
INSTALL_SHARE = Path(os.environ["FIPER_ROOT"]) / "install" / "fiper_msgs" / "share" / "fiper_msgs" / "msg"


@pytest.fixture(scope="module")
def typestore():  # noqa: ANN201 - rosbags' Typestore type is internal
    store = get_typestore(Stores.ROS2_JAZZY)
    types = {}
    for path in sorted(MSG_DIR.glob("*.msg")):
        types.update(get_types_from_msg(path.read_text(), f"fiper_msgs/msg/{path.stem}"))
    store.register(types)
    return store


def _plain(value: object) -> object:
    """Nested plain data of a rosbags message, arrays and floats by their bytes."""
    if hasattr(value, "__dataclass_fields__"):
        return {k: _plain(getattr(value, k)) for k in value.__dataclass_fields__ if k != "__msgtype__"}
    if isinstance(value, np.ndarray):
        return (value.dtype.str, value.tobytes())
    if isinstance(value, float):
        return np.float64(value).tobytes()
    if isinstance(value, list):
        return [_plain(v) for v in value]
    return value


def test_rclpy_and_rosbags_decode_each_others_cdr(typestore) -> None:  # noqa: ANN001
    for name, msg in sample_messages().items():
        decoded = typestore.deserialize_cdr(serialize_message(msg), name)
        back = deserialize_message(bytes(typestore.serialize_cdr(decoded, name)), type(msg))
        assert as_plain(back) == as_plain(msg), name


def test_every_type_round_trips_through_an_mcap_bag(tmp_path: Path, typestore) -> None:  # noqa: ANN001
    bag = tmp_path / "bag"
    written: dict[str, bytes] = {}
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for i, (name, msg) in enumerate(sample_messages().items()):
            raw = serialize_message(msg)
            conn = writer.add_connection(topic_of(name), name, typestore=typestore)
            writer.write(conn, 1_000_000_000 + i, raw)
            written[name] = raw
    assert (bag / "metadata.yaml").read_text().count("version: 9") == 1
    assert list(bag.glob("*.mcap"))

    read: dict[str, bytes] = {}
    with AnyReader([bag]) as reader:  # no typestore: definitions come from the bag itself
        for conn, _, raw in reader.messages():
            read[conn.msgtype] = bytes(raw)
            original = typestore.deserialize_cdr(written[conn.msgtype], conn.msgtype)
            assert _plain(reader.deserialize(raw, conn.msgtype)) == _plain(original), conn.msgtype
    assert read == written


def test_rihs01_hash_of_rosbags_equals_rosidls(typestore) -> None:  # noqa: ANN001
    names = [p.stem for p in sorted(MSG_DIR.glob("*.msg"))]
    assert len(names) == len(sample_messages())
    for stem in names:
        generated = json.loads((INSTALL_SHARE / f"{stem}.json").read_text())
        hashes = {h["type_name"]: h["hash_string"] for h in generated["type_hashes"]}
        type_name = f"fiper_msgs/msg/{stem}"
        assert hashes[type_name].startswith("RIHS01_")
        assert typestore.hash_rihs01(type_name) == hashes[type_name], stem
