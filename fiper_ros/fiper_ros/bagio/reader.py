"""Reading rosbag2 bags with ``rosbags.highlevel.AnyReader`` (types from the bag's own definitions).

Every problem becomes a :class:`~fiper_ros.bagio.errors.BagError` of one line naming the bag or file: a
missing or malformed ``metadata.yaml``, an empty, foreign or truncated MCAP file
(:func:`fiper_ros.bagio.storage.check_mcap`, before ``rosbags`` opens it; an unfinished bag is read through a
recovered copy if :func:`find_bags` was allowed to make one), corrupt MCAP data, a message
that does not decode, and a schema topic whose type or definition (RIHS01 hash) is not the installed
``fiper_msgs`` one (:meth:`BagReader.check_schema`).
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection, Qos

from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.recover import read_unfinished, readable_copy, unfinished
from fiper_ros.bagio.schema import BagInfo, typestore
from fiper_ros.bagio.storage import METADATA, bag_directories, check_mcap, read_metadata, storage_files
from fiper_ros.interface.topics import TOPICS


def find_bags(paths: Iterable[Path], *, strict: bool = True) -> list[Path]:
    """The bags named by ``paths``: a bag directory itself, or every bag below a directory (sorted; hidden
    directories, such as a writer's staging, left out). An unfinished bag (MCAP data without
    ``metadata.yaml``, or an MCAP file that does not end) is refused with ``strict``; else it is recovered
    into a temporary copy that :class:`BagReader` reads, with a one-line :class:`~fiper_ros.errors.FiperWarning`
    (``fiper COMMAND: warning: ...``)."""
    bags = bag_directories(paths)
    for bag in bags:
        reason = unfinished(bag)
        if reason is None:
            continue
        if strict:
            raise BagError(f"{reason}; 'fiper bag recover {bag}' finishes it")
        read_unfinished(bag)
    return bags


@dataclass(frozen=True)
class BagMessage:
    """One message of a bag."""

    topic: str
    msgtype: str
    log_time_ns: int
    raw: bytes


class BagReader:
    """One open bag: its ``custom_data``, topics, offered QoS and messages in log-time order.

    Use as a context manager: ``with BagReader(path) as bag: for m in bag.messages(): ...``.
    """

    def __init__(self, path: Path) -> None:
        self.path = Path(path)
        self._data = readable_copy(self.path) or self.path
        """Where the bag's files are: the bag, or the recovered copy of an unfinished bag (:func:`find_bags`)."""
        if not (self._data / METADATA).is_file():
            raise BagError(f"{self.path}: not a rosbag2 bag (no {METADATA})")
        metadata = read_metadata(self._data)
        self.info = BagInfo.from_custom_data(metadata.get("custom_data"), str(self.path))
        self._files = storage_files(self._data, metadata)
        self._reader: AnyReader | None = None

    def __enter__(self) -> BagReader:
        for file in self._files:
            check_mcap(file)
        try:
            self._reader = AnyReader([self._data])
            self._reader.open()
        except Exception as error:  # any rosbags/MCAP failure is a bad bag
            self._reader = None
            raise BagError(f"{self.path}: cannot open the bag ({type(error).__name__}: {error})") from error
        try:
            self.check_schema()
        except BagError:
            self.__exit__(None, None, None)
            raise
        return self

    def check_schema(self) -> None:
        """Every schema topic the bag holds has the schema's type, defined as the installed ``fiper_msgs``
        defines it (same RIHS01 type hash): its messages are decoded and published as that type."""
        ours = typestore()
        for connection in self.reader.connections:
            spec = TOPICS.get(connection.topic)
            if spec is None:
                continue
            if connection.msgtype != spec.msgtype:
                raise BagError(f"{self.path}: topic {connection.topic} holds {connection.msgtype}, the FIPER schema "
                               f"says {spec.msgtype} (not a bag of this suite)")
            theirs, expected = self.reader.typestore.hash_rihs01(spec.msgtype), ours.hash_rihs01(spec.msgtype)
            if theirs != expected:
                raise BagError(f"{self.path}: its definition of {spec.msgtype} (on {connection.topic}, {theirs}) is "
                               f"not the installed one ({expected}): recorded with another version of the message")

    def require_any(self, topics: Sequence[str]) -> None:
        """Refuse a bag that holds none of ``topics`` (e.g. a bag of other data)."""
        if not set(topics) & set(self.topics):
            held = ", ".join(f"{t} ({m})" for t, m in sorted(self.topics.items())) or "none"
            raise BagError(f"{self.path}: none of the FIPER topics {', '.join(topics)} (its topics: {held})")

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if self._reader is not None:
            self._reader.close()
            self._reader = None

    @property
    def reader(self) -> AnyReader:
        """The open ``AnyReader``."""
        if self._reader is None:
            raise BagError(f"{self.path}: bag is not open")
        return self._reader

    @property
    def topics(self) -> dict[str, str]:
        """Topic -> message type."""
        return {c.topic: c.msgtype for c in self.reader.connections}

    def offered_qos(self, topic: str) -> list[Qos]:
        """The QoS profiles recorded for ``topic``'s publishers."""
        return [q for c in self.reader.connections if c.topic == topic
                for q in getattr(c.ext, "offered_qos_profiles", [])]

    @property
    def start_ns(self) -> int:
        """Log time of the first message."""
        return int(self.reader.start_time)

    @property
    def end_ns(self) -> int:
        """Log time of the last message."""
        return int(self.reader.end_time)

    def messages(self, topics: Sequence[str] | None = None) -> Iterator[BagMessage]:
        """Messages of ``topics`` (default: all) in log-time order."""
        connections: list[Connection] = [c for c in self.reader.connections if topics is None or c.topic in topics]
        if not connections:
            return
        try:
            for connection, log_time, raw in self.reader.messages(connections=connections):
                yield BagMessage(connection.topic, connection.msgtype, int(log_time), bytes(raw))
        except Exception as error:  # corrupt chunk data (truncation is refused on opening)
            raise BagError(f"{self.path}: corrupt MCAP data ({type(error).__name__}: {error})") from error

    def check_data(self) -> None:
        """Read every chunk once (decompressed, checked against its CRC), so a corrupt bag is refused
        before anything is done with its first messages."""
        for _ in self.messages():
            pass

    def decode(self, message: BagMessage) -> Any:
        """The message as a ``rosbags`` object (types from the bag's embedded definitions, which
        :meth:`check_schema` found equal to ours for the schema topics: a failure is corrupt data)."""
        try:
            return self.reader.deserialize(message.raw, message.msgtype)
        except Exception as error:  # a message that does not match its type
            raise BagError(f"{self.path}: corrupt MCAP data: a {message.msgtype} message on {message.topic} at "
                           f"{message.log_time_ns} ns does not decode ({error})") from error
