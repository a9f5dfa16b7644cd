"""The MCAP files of a bag: checked before ``rosbags`` reads them, and given chunk checksums when
written. The reader layer's one home for "this file is empty, not MCAP, cut short or corrupt"
(docs/reliability.md, "Bags and calibration files").

An MCAP file (https://mcap.dev/spec) begins and ends with the magic bytes; in between come records
(opcode byte, uint64 length, body): a header, the data section (chunks of messages and their message
indexes), a data-end record, the summary section and the footer. A recording that did not finish (a
killed recorder, a full disk) or a file cut in transfer lacks the trailing magic; :func:`check_mcap`
then walks the records from the start and says where the file ends: inside which record, after how
many complete chunks. A truncated file is refused for now; reading it up to its last complete chunk
would start from that walk.

A chunk record has a CRC-32 of its uncompressed records, which ``rosbags`` checks on reading but
writes as 0 ("not computed"): :func:`add_chunk_crcs` fills it in, so a byte changed inside a chunk of a
bag of this suite is refused ("Chunk checksum mismatch") instead of read as other values.
"""
from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from rosbags.rosbag2.storage_mcap import decompress

from fiper_ros.bags.errors import BagError

MAGIC = b"\x89MCAP0\r\n"
#: opcode + uint64 body length
RECORD_HEAD = 9
HEADER, CHUNK, DATA_END, FOOTER = 0x01, 0x06, 0x0F, 0x02
RECORD_NAMES = {HEADER: "header", FOOTER: "footer", 0x03: "schema", 0x04: "channel", 0x05: "message", CHUNK: "chunk",
                0x07: "message index", 0x08: "chunk index", 0x09: "attachment", 0x0A: "attachment index",
                0x0B: "statistics", 0x0C: "metadata", 0x0D: "metadata index", 0x0E: "summary offset",
                DATA_END: "data end"}
#: Offset of ``uncompressed_crc`` in a chunk body (after start time, end time, uncompressed size).
CHUNK_CRC_OFFSET = 24


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


def add_chunk_crcs(path: Path) -> None:
    """Write the CRC-32 of every chunk's uncompressed records into its ``uncompressed_crc`` (in place:
    no offset changes)."""
    size = path.stat().st_size
    with path.open("r+b") as stream:
        for record in [r for r in _records(stream, size) if r.opcode == CHUNK]:
            stream.seek(record.position + RECORD_HEAD)
            body = stream.read(record.length)
            (uncompressed_size,) = struct.unpack_from("<Q", body, 16)
            (name_length,) = struct.unpack_from("<I", body, 28)
            compression = body[32:32 + name_length].decode()
            data = body[32 + name_length + 8:]
            raw = decompress(data, compression, uncompressed_size, 0)
            stream.seek(record.position + RECORD_HEAD + CHUNK_CRC_OFFSET)
            stream.write(struct.pack("<I", zlib.crc32(raw)))


def check_mcap(path: Path) -> None:
    """Raise :class:`BagError` unless ``path`` is a whole MCAP file (both magics; the records are read later)."""
    try:
        size = path.stat().st_size
        with path.open("rb") as stream:
            head = stream.read(len(MAGIC))
            stream.seek(max(0, size - len(MAGIC)))
            tail = stream.read()
    except FileNotFoundError as error:
        raise BagError(f"{path}: missing (metadata.yaml lists it)") from error
    except OSError as error:
        raise BagError(f"{path}: unreadable ({error.strerror or error})") from error
    if size == 0:
        raise BagError(f"{path}: empty file (0 bytes), not an MCAP file")
    if head != MAGIC[: len(head)]:
        raise BagError(f"{path}: not an MCAP file (it does not begin with the MCAP magic bytes)")
    if size < 2 * len(MAGIC) or tail != MAGIC:
        where = "cut inside the leading magic" if size < len(MAGIC) else _where_cut(path, size)
        raise BagError(f"{path}: truncated MCAP file of {size} bytes ({where}): the recording did not finish, "
                       "or the file was cut")
