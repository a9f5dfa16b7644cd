"""The files of a bag: ``metadata.yaml`` and its MCAP files, checked before ``rosbags`` reads them, and the
readable part of an MCAP file that did not finish. The reader layer's one home for "this file is empty,
not MCAP, cut short or corrupt" (docs/reliability.md, "Bags and calibration files" and "Recordings").

An MCAP file (https://mcap.dev/spec) begins and ends with the magic bytes; in between come records
(opcode byte, uint64 length, body): a header, the data section (chunks of messages, each followed by its
message indexes, and metadata records), a data-end record, the summary section (schemas, channels, one
chunk index per chunk, statistics) and the footer. A recording that did not finish (a killed recorder, a
power cut, a full disk) or a file cut in transfer lacks the summary and the trailing magic;
:func:`check_mcap` then walks the records from the start and says where the file ends: inside which
record, after how many complete chunks. :class:`Salvage` reads such a file up to its last complete,
intact chunk (each chunk is self-contained: the schema and channel records of its messages come before
them in the same or an earlier chunk), which is what a crash leaves readable.

Every chunk carries the CRC-32 of its uncompressed records (the suite's writer fills it in; ``rosbags``
checks it on reading), so a byte changed inside a chunk is refused ("Chunk checksum mismatch") instead of
read as other values, and a chunk a power cut left half on disk ends a salvage instead of being read.
"""
from __future__ import annotations

import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from io import BytesIO
from pathlib import Path
from typing import Any, BinaryIO

import yaml
from mcap.data_stream import ReadDataStream
from mcap.records import Channel, Chunk, McapRecord, Message, Metadata, Schema
from mcap.stream_reader import breakup_chunk

from fiper_ros.bagio.errors import BagError

METADATA = "metadata.yaml"
MAGIC = b"\x89MCAP0\r\n"
#: opcode + uint64 body length
RECORD_HEAD = 9
HEADER, FOOTER, SCHEMA, CHANNEL, MESSAGE, CHUNK, MESSAGE_INDEX = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x07
ATTACHMENT, METADATA_RECORD, DATA_END = 0x09, 0x0C, 0x0F
RECORD_NAMES = {HEADER: "header", FOOTER: "footer", SCHEMA: "schema", CHANNEL: "channel", MESSAGE: "message",
                CHUNK: "chunk", MESSAGE_INDEX: "message index", 0x08: "chunk index", ATTACHMENT: "attachment",
                0x0A: "attachment index", 0x0B: "statistics", METADATA_RECORD: "metadata", 0x0D: "metadata index",
                0x0E: "summary offset", DATA_END: "data end"}
#: Records a salvage skips: they index or attach, they hold no message.
SKIPPED = {MESSAGE_INDEX, ATTACHMENT}
#: Largest uncompressed chunk a salvage decompresses (the suite writes chunks of ``--chunk-mb``, 1 MiB by
#: default); a larger size field is damage.
MAX_CHUNK_BYTES = 1 << 30


def _below(root: Path, pattern: str) -> Iterator[Path]:
    """Files matching ``pattern`` below ``root``, outside hidden directories (a writer's staging)."""
    return (f for f in root.rglob(pattern) if not any(part.startswith(".") for part in f.relative_to(root).parts))


def bag_directories(paths: Iterable[Path]) -> list[Path]:
    """The bag directories named by ``paths``, finished (``metadata.yaml``) or not (MCAP data only): a bag
    directory itself, or every bag below a directory (sorted; hidden directories left out)."""
    found: list[Path] = []
    for path in map(Path, paths):
        if (path / METADATA).is_file() or (path.is_dir() and any(path.glob("*.mcap"))):
            found.append(path)
        elif path.is_file() and path.suffix == ".mcap":
            raise BagError(f"{path}: give the bag directory (the one with {METADATA}), not the .mcap file")
        elif path.is_dir():
            below = sorted({f.parent for pattern in (METADATA, "*.mcap") for f in _below(path, pattern)})
            if not below:
                raise BagError(f"{path}: no bag ({METADATA}) in this directory")
            found.extend(below)
        else:
            raise BagError(f"{path}: no such bag")
    return found


def read_metadata(path: Path) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` mapping of the bag directory ``path``."""
    try:
        with (path / METADATA).open() as stream:
            content = yaml.safe_load(stream)
    except (OSError, yaml.YAMLError) as error:
        raise BagError(f"{path}: unreadable {METADATA}: {error}") from error
    info = content.get("rosbag2_bagfile_information") if isinstance(content, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{path}: {METADATA} is not rosbag2 metadata")
    return info


def storage_files(path: Path, metadata: dict[str, Any]) -> list[Path]:
    """The MCAP files ``metadata.yaml`` lists (none for another storage plugin)."""
    if metadata.get("storage_identifier") != "mcap":
        return []
    names = metadata.get("relative_file_paths")
    if not isinstance(names, list) or not names:
        raise BagError(f"{path}: {METADATA} lists no storage files (relative_file_paths)")
    return [path / str(name) for name in names]


@dataclass(frozen=True)
class Record:
    """Where one record lies in the file."""

    position: int
    opcode: int
    length: int

    @property
    def end(self) -> int:
        """Offset just after the record."""
        return self.position + RECORD_HEAD + self.length


def _records(stream: BinaryIO, size: int) -> Iterator[Record]:
    """The records after the leading magic in file order, up to the end or the first record the file
    cuts (yielded too: its ``end`` lies beyond ``size``); a partial record head ends the walk."""
    position = len(MAGIC)
    while position + RECORD_HEAD <= size:
        stream.seek(position)
        head = stream.read(RECORD_HEAD)
        record = Record(position, head[0], struct.unpack("<Q", head[1:])[0])
        yield record
        if record.end > size:
            return
        position = record.end


def _section(last: int | None, summary: bool) -> str:
    """Where a record boundary lies, given the last complete record and whether the summary began."""
    if last == DATA_END:
        return "after the data section, before the summary"
    return "in the summary section" if summary else "in the data section"


def _where_cut(path: Path, size: int) -> str:
    """Where a file without its trailing magic ends: the record it ends in and the complete chunks before."""
    chunks, summary, last, position = 0, False, None, len(MAGIC)
    with path.open("rb") as stream:
        for record in _records(stream, size):
            if record.end > size:
                if record.opcode == HEADER:
                    return "cut inside the header record"
                name = RECORD_NAMES.get(record.opcode, f"unknown (opcode {record.opcode:#04x})")
                return (f"cut inside a {name} record at byte {record.position} {_section(last, summary)}, "
                        f"after {chunks} complete chunk(s)")
            summary = summary or last == DATA_END
            chunks += record.opcode == CHUNK
            last, position = record.opcode, record.end
    if last is None:
        return "cut inside the header record" if position < size else "cut right after the leading magic"
    if last == FOOTER:
        return f"cut inside the trailing magic, after the footer and {chunks} complete chunk(s)"
    inside = " inside a record's opcode and length" if position < size else ""
    return f"cut at byte {position}{inside} {_section(last, summary)}, after {chunks} complete chunk(s)"


class TruncatedMcap(BagError):
    """An MCAP file that begins as one but does not end: an unfinished recording, or a file cut short."""


def check_mcap(path: Path) -> None:
    """Raise :class:`BagError` unless ``path`` is a whole MCAP file (both magics; the records are read later);
    :class:`TruncatedMcap` if it begins as one and does not end."""
    try:
        size = path.stat().st_size
        with path.open("rb") as stream:
            head = stream.read(len(MAGIC))
            stream.seek(max(0, size - len(MAGIC)))
            tail = stream.read()
    except FileNotFoundError as error:
        raise BagError(f"{path}: missing ({METADATA} lists it)") from error
    except OSError as error:
        raise BagError(f"{path}: unreadable ({error.strerror or error})") from error
    if size == 0:
        raise BagError(f"{path}: empty file (0 bytes), not an MCAP file")
    if head != MAGIC[: len(head)]:
        raise BagError(f"{path}: not an MCAP file (it does not begin with the MCAP magic bytes)")
    if size < 2 * len(MAGIC) or tail != MAGIC:
        where = "cut inside the leading magic" if size < len(MAGIC) else _where_cut(path, size)
        raise TruncatedMcap(f"{path}: truncated MCAP file of {size} bytes ({where}): the recording did not finish, "
                            "or the file was cut")


class Salvage:
    """The readable part of one MCAP file, whole or not: the schema, channel, message and metadata records
    of its data section in file order, up to the data end or to the first record the file cuts or that is
    damaged (a chunk that does not decompress or fails its CRC-32; bytes that are no record).

    Iterate :meth:`records` once; then :attr:`chunks` is the number of chunks read and :attr:`end` says why
    the walk stopped before the data end ("" if it reached it)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self.chunks = 0
        self.end = ""
        try:
            check_mcap(self.path)
        except TruncatedMcap as cut:
            self.end = str(cut)

    def records(self) -> Iterator[McapRecord]:
        """The records (:class:`mcap.records.Schema`, ``Channel``, ``Message``, ``Metadata``) in file order."""
        size = self.path.stat().st_size
        with self.path.open("rb") as stream:
            for record in _records(stream, size):
                if record.end > size:
                    return  # the cut that check_mcap described
                if record.opcode == DATA_END:
                    return
                if record.opcode in SKIPPED or (record.opcode == HEADER and record.position == len(MAGIC)):
                    continue
                stream.seek(record.position + RECORD_HEAD)
                body = ReadDataStream(BytesIO(stream.read(record.length)))
                try:
                    found = self._parse(record, body)
                except Exception as error:  # noqa: BLE001 - whatever a damaged record raises ends the walk
                    self.end = (f"{self.path}: damaged {RECORD_NAMES.get(record.opcode, 'record')} record at byte "
                                f"{record.position} ({type(error).__name__}: {error}), after {self.chunks} complete "
                                "chunk(s)")
                    return
                if found is None:
                    self.end = (f"{self.path}: no MCAP record at byte {record.position} (opcode {record.opcode:#04x}), "
                                f"after {self.chunks} complete chunk(s)")
                    return
                yield from found
                self.chunks += record.opcode == CHUNK
        if not self.end:  # the file ends without a data end, and yet with the trailing magic
            self.end = f"{self.path}: no data end record, after {self.chunks} complete chunk(s)"

    @staticmethod
    def _parse(record: Record, body: ReadDataStream) -> list[McapRecord] | None:
        """The records one data-section record holds; None if it is not one a data section holds."""
        if record.opcode == CHUNK:
            chunk = Chunk.read(body)
            if not 0 < chunk.uncompressed_size <= MAX_CHUNK_BYTES:  # 0: zeros, the blocks a power cut left unwritten
                raise ValueError(f"a chunk of {chunk.uncompressed_size} bytes (1 to {MAX_CHUNK_BYTES} expected)")
            return [r for r in breakup_chunk(chunk, validate_crc=True) if isinstance(r, (Schema, Channel, Message))]
        if record.opcode == SCHEMA:
            return [Schema.read(body)]
        if record.opcode == CHANNEL:
            return [Channel.read(body)]
        if record.opcode == MESSAGE:
            return [Message.read(body, record.length)]
        if record.opcode == METADATA_RECORD:
            return [Metadata.read(body)]
        return None
