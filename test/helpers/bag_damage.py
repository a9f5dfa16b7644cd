"""The failure classes of bags (docs/reliability.md, "Bags and calibration files"): each a function that
damages a copy of a good bag in place and returns the text the refusal must hold (naming the file), for
the command table of test/bags/test_errors.py (calibration directories: helpers.calibration_damage).

Bags are written by the project's own writer (:func:`fiper_ros.bagio.rollout_bags.write_rollouts`), then cut,
overwritten or rewritten. The MCAP record walk here is the test's own (opcode byte, uint64 length, body;
mcap.dev/spec), independent of the one in :mod:`fiper_ros.bagio.storage`.
"""
from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import zstandard
from helpers.synthetic import make_rollout
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fiper_ros.bagio.reader import BagReader
from fiper_ros.bagio.rollout_bags import write_rollouts
from fiper_ros.bagio.schema import BagInfo, message_definitions, typestore
from fiper_ros.bagio.writer import BagWriter
from fiper_ros.interface.topics import EMBEDDING_TOPIC

#: A damage: modifies the bag at the path, returns the text its refusal holds.
Damage = Callable[[Path], str]

CHUNK, DATA_END, FOOTER = 0x06, 0x0F, 0x02
MAGIC = b"\x89MCAP0\r\n"
#: Rollouts of the recorded bag: long enough for several 1 MiB MCAP chunks.
RECORDED_ROLLOUTS, RECORDED_LENGTH = 20, 60


def write_recorded_bag(path: Path) -> Path:
    """A bag of 20 successful synthetic rollouts of 60 steps (more than two MCAP chunks), split calibration."""
    rollouts = [make_rollout(seed, length=RECORDED_LENGTH) for seed in range(RECORDED_ROLLOUTS)]
    info = BagInfo(task="synthetic", synthetic=True, source="test", split="calibration")
    write_rollouts(path, rollouts, list(range(1, RECORDED_ROLLOUTS + 1)), info)
    return path


# -- MCAP files ------------------------------------------------------------------------------------

def mcap_of(bag: Path) -> Path:
    """The bag's one MCAP file."""
    (mcap,) = bag.glob("*.mcap")
    return mcap


def records(data: bytes) -> list[tuple[int, int, int]]:
    """``(position, opcode, end)`` of every record of a whole MCAP file (of a cut one: up to the cut)."""
    position, found = 8, []
    while position + 9 <= len(data) - (8 if data.endswith(MAGIC) else 0):
        end = position + 9 + int.from_bytes(data[position + 1:position + 9], "little")
        if end > len(data):
            break
        found.append((position, data[position], end))
        position = end
    return found


def chunk_messages(data: bytes) -> list[int]:
    """Messages per complete chunk of an MCAP file (cut or not), in file order: every chunk record whole in
    ``data`` decompressed (zstd) and its message records (opcode 0x05) counted."""
    counts = []
    for position, opcode, end in records(data):
        if opcode != CHUNK:
            continue
        body = data[position + 9:end]
        size = int.from_bytes(body[16:24], "little")
        name_length = int.from_bytes(body[28:32], "little")
        compression = body[32:32 + name_length].decode()
        payload = body[32 + name_length + 8:]
        inner = zstandard.ZstdDecompressor().decompress(payload, max_output_size=size) if compression else payload
        count, offset = 0, 0
        while offset < len(inner):
            count += inner[offset] == 0x05
            offset += 9 + int.from_bytes(inner[offset + 1:offset + 9], "little")
        counts.append(count)
    return counts


def _cut(bag: Path, at: Callable[[list[tuple[int, int, int]], int], int], where: Callable[[int, int], str]) -> str:
    """Cut the bag's MCAP file at ``at(records, size)``; ``where(offset, chunks)`` is the expected place."""
    mcap = mcap_of(bag)
    data = mcap.read_bytes()
    found = records(data)
    offset = at(found, len(data))
    mcap.write_bytes(data[:offset])
    chunks = sum(opcode == CHUNK for _, opcode, _ in found)
    return f"{mcap}: truncated MCAP file of {offset} bytes ({where(offset, chunks)}): the recording did not finish"


def _chunk_positions(found: list[tuple[int, int, int]]) -> list[int]:
    return [position for position, opcode, _ in found if opcode == CHUNK]


def _end_of(found: list[tuple[int, int, int]], opcode: int) -> int:
    return next(end for _, op, end in found if op == opcode)


def _start_of(found: list[tuple[int, int, int]], opcode: int) -> int:
    return next(position for position, op, _ in found if op == opcode)


def zero_bytes(bag: Path) -> str:
    mcap = mcap_of(bag)
    mcap.write_bytes(b"")
    return f"{mcap}: empty file (0 bytes), not an MCAP file"


def random_bytes(bag: Path) -> str:
    mcap = mcap_of(bag)
    mcap.write_bytes(np.random.default_rng(0).bytes(4096))
    return f"{mcap}: not an MCAP file (it does not begin with the MCAP magic bytes)"


def cut_inside_header(bag: Path) -> str:
    return _cut(bag, lambda found, size: 20, lambda offset, chunks: "cut inside the header record")


def cut_inside_a_chunk(bag: Path) -> str:
    return _cut(bag, lambda found, size: _chunk_positions(found)[1] + 1000,
                lambda offset, chunks: f"cut inside a chunk record at byte {offset - 1000} in the data section, "
                                       "after 1 complete chunk(s)")


def cut_between_chunks(bag: Path) -> str:
    return _cut(bag, lambda found, size: _chunk_positions(found)[1],
                lambda offset, chunks: f"cut at byte {offset} in the data section, after 1 complete chunk(s)")


def cut_before_the_summary(bag: Path) -> str:
    return _cut(bag, lambda found, size: _end_of(found, DATA_END),
                lambda offset, chunks: f"cut at byte {offset} after the data section, before the summary, after "
                                       f"{chunks} complete chunk(s)")


def cut_before_the_footer(bag: Path) -> str:
    return _cut(bag, lambda found, size: _start_of(found, FOOTER),
                lambda offset, chunks: f"cut at byte {offset} in the summary section, after {chunks} complete chunk(s)")


def cut_inside_the_trailing_magic(bag: Path) -> str:
    return _cut(bag, lambda found, size: size - 3,
                lambda offset, chunks: f"cut inside the trailing magic, after the footer and {chunks} complete "
                                       "chunk(s)")


def changed_byte_in_a_chunk(bag: Path) -> str:
    """One byte of the first chunk's compressed records changed (the file keeps its size and structure)."""
    mcap = mcap_of(bag)
    data = bytearray(mcap.read_bytes())
    data[_chunk_positions(records(bytes(data)))[0] + 5000] ^= 0xFF
    mcap.write_bytes(bytes(data))
    return f"{bag}: corrupt MCAP data (ReaderError: Chunk checksum mismatch.)"


# -- metadata.yaml --------------------------------------------------------------------------------

def _edit_metadata(bag: Path, old: str, new: str) -> None:
    path = bag / "metadata.yaml"
    text = path.read_text()
    assert old in text, old
    path.write_text(text.replace(old, new))


def no_metadata(bag: Path) -> str:
    (bag / "metadata.yaml").unlink()
    return f"{bag}: MCAP data but no metadata.yaml: not a finished rosbag2 bag"


def metadata_not_yaml(bag: Path) -> str:
    (bag / "metadata.yaml").write_text("rosbag2_bagfile_information: [version: 9,\n")
    return f"{bag}: unreadable metadata.yaml: while parsing"


def metadata_of_another_tool(bag: Path) -> str:
    (bag / "metadata.yaml").write_text("just: text\n")
    return f"{bag}: metadata.yaml is not rosbag2 metadata"


def newer_rosbag2_version(bag: Path) -> str:
    _edit_metadata(bag, "\n  version: 9\n", "\n  version: 99\n")
    return f"{bag}: cannot open the bag (AnyReaderError: Rosbag2 version 99 not supported"


def newer_fiper_schema(bag: Path) -> str:
    _edit_metadata(bag, "fiper_schema: '1'", "fiper_schema: '2'")
    return f"{bag}: FIPER bag schema version '2' not supported (this code reads '1')"


def storage_file_missing(bag: Path) -> str:
    mcap = mcap_of(bag)
    mcap.unlink()
    return f"{mcap}: missing (metadata.yaml lists it)"


# -- bags of other schemas ------------------------------------------------------------------------

STRING = "std_msgs/msg/String"


def _string_bag(bag: Path, topic: str) -> None:
    """Replace the bag by one of a std_msgs String on ``topic`` (written by the project's writer)."""
    shutil.rmtree(bag)
    store = typestore()
    with BagWriter(bag) as writer:
        writer.info = BagInfo(task="synthetic", split="calibration", source="test")
        writer.add_topic(topic, STRING)
        writer.write(topic, 1_700_000_000 * 10**9, bytes(store.serialize_cdr(store.types[STRING]("hello"), STRING)))


def only_std_msgs(bag: Path) -> str:
    _string_bag(bag, "/chatter")
    return f"{bag}: none of the FIPER topics"


def std_msgs_on_a_fiper_topic(bag: Path) -> str:
    _string_bag(bag, EMBEDDING_TOPIC)
    return (f"{bag}: topic {EMBEDDING_TOPIC} holds {STRING}, the FIPER schema says fiper_msgs/msg/ObservationEmbedding "
            "(not a bag of this suite)")


def other_definition_of_a_fiper_type(bag: Path) -> str:
    """The same messages, recorded with an ObservationEmbedding whose ``step`` is a uint64 (another RIHS01)."""
    types = {}
    for path in sorted(message_definitions().glob("*.msg")):
        text = path.read_text()
        if path.stem == "ObservationEmbedding":
            text = text.replace("uint32 step", "uint64 step")
        types.update(get_types_from_msg(text, f"fiper_msgs/msg/{path.stem}"))
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(types)
    source = bag.with_name(f"{bag.name}.source")
    bag.rename(source)
    with BagReader(source) as reader, Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for message in reader.messages():
            if message.topic not in connections:
                connections[message.topic] = writer.add_connection(message.topic, message.msgtype, typestore=store)
            writer.write(connections[message.topic], message.log_time_ns, message.raw)
    shutil.rmtree(source)
    return f"{bag}: its definition of fiper_msgs/msg/ObservationEmbedding (on {EMBEDDING_TOPIC}, RIHS01_"


#: The damages after which a bag is unfinished, not unreadable: it is read up to its last complete chunk
#: (docs/reliability.md, "Recordings"), and refused with --strict (the text its damage returns).
UNFINISHED = ("cut_inside_a_chunk", "cut_between_chunks", "cut_before_the_summary", "cut_before_the_footer",
              "cut_inside_the_trailing_magic", "no_metadata")

BAG_DAMAGES: dict[str, Damage] = {damage.__name__: damage for damage in (
    zero_bytes, random_bytes, cut_inside_header, cut_inside_a_chunk, cut_between_chunks, cut_before_the_summary,
    cut_before_the_footer, cut_inside_the_trailing_magic, changed_byte_in_a_chunk, no_metadata, metadata_not_yaml,
    metadata_of_another_tool, newer_rosbag2_version, newer_fiper_schema, storage_file_missing, only_std_msgs,
    std_msgs_on_a_fiper_topic, other_definition_of_a_fiper_type)}


# -- what a killed live recorder leaves -------------------------------------------------------------

#: Steps (embedding + action batch) per closed chunk of :func:`write_and_die`, and the steps left in its open chunk.
STEPS_PER_CHUNK, OPEN_STEPS = 5, 2
#: ``custom_data`` of :func:`write_and_die`'s bag.
LIVE_INFO = BagInfo(task="synthetic", calibration_hash="c0ffee", source="fiper record", split="test")


def live_stream(chunks: int) -> list[tuple[str, int, bytes]]:
    """``(topic, log time, CDR)`` of :func:`write_and_die`: a START, then ``chunks`` chunks' worth of steps and
    :data:`OPEN_STEPS` more."""
    from helpers.stream import start_cdr, step_cdr  # the stream helpers import the DDS harness

    rollout = make_rollout(7, length=STEPS_PER_CHUNK * chunks + OPEN_STEPS)
    stream = [("/fiper/rollout_events", 1_000, start_cdr(9))]
    for step in range(rollout.length):
        stream.extend((topic, 2_000 + step, raw) for topic, raw in step_cdr(9, step, rollout))
    return stream


def write_and_die(path: str, chunks: int) -> None:
    """Write :func:`live_stream` as a live bag, closing ``chunks`` chunks of :data:`STEPS_PER_CHUNK` steps each (the
    first holds the START too), then die by SIGKILL with :data:`OPEN_STEPS` steps in the open chunk."""
    import os
    import signal

    from fiper_ros.bagio.chunks import LiveChunks

    writer = BagWriter(Path(path), live=LiveChunks(seconds=3600.0, megabytes=100.0))
    writer.info = LIVE_INFO
    for index, (topic, time_ns, raw) in enumerate(live_stream(chunks)):
        writer.write(topic, time_ns, raw)
        if index and index % (2 * STEPS_PER_CHUNK) == 0 and index <= 2 * STEPS_PER_CHUNK * chunks:
            writer.flush()
    os.kill(os.getpid(), signal.SIGKILL)
