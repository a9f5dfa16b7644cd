"""Reading rosbag2 bags with ``rosbags.highlevel.AnyReader`` (types from the bag's own definitions).

Every problem (missing or malformed ``metadata.yaml``, a truncated or corrupt MCAP file, a message
that does not decode) becomes a :class:`~fiper_ros.bags.errors.BagError` naming the bag.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

import yaml
from rosbags.highlevel import AnyReader
from rosbags.interfaces import Connection, Qos

from fiper_ros.bags.errors import BagError
from fiper_ros.bags.schema import BagInfo

METADATA = "metadata.yaml"


def find_bags(paths: Iterable[Path]) -> list[Path]:
    """The bags named by ``paths``: a bag directory itself, or every bag below a directory (sorted)."""
    found: list[Path] = []
    for path in map(Path, paths):
        if (path / METADATA).is_file():
            found.append(path)
        elif path.is_file() and path.suffix == ".mcap":
            raise BagError(f"{path}: give the bag directory (the one with {METADATA}), not the .mcap file")
        elif path.is_dir():
            below = sorted(p.parent for p in path.rglob(METADATA)
                           if not any(part.startswith(".") for part in p.relative_to(path).parts))
            if not below:
                raise BagError(f"{path}: no bag ({METADATA}) in this directory")
            found.extend(below)
        else:
            raise BagError(f"{path}: no such bag")
    return found


def _read_metadata(path: Path) -> dict[str, Any]:
    try:
        content = yaml.safe_load((path / METADATA).read_text())
    except (OSError, yaml.YAMLError) as error:
        raise BagError(f"{path}: unreadable {METADATA}: {error}") from error
    info = content.get("rosbag2_bagfile_information") if isinstance(content, dict) else None
    if not isinstance(info, dict):
        raise BagError(f"{path}: {METADATA} is not rosbag2 metadata")
    return info


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
        if not (self.path / METADATA).is_file():
            raise BagError(f"{self.path}: not a rosbag2 bag (no {METADATA})")
        metadata = _read_metadata(self.path)
        self.info = BagInfo.from_custom_data(metadata.get("custom_data"), str(self.path))
        self._reader: AnyReader | None = None

    def __enter__(self) -> BagReader:
        try:
            self._reader = AnyReader([self.path])
            self._reader.open()
        except Exception as error:  # noqa: BLE001 - any rosbags/MCAP failure is a bad bag
            self._reader = None
            raise BagError(f"{self.path}: cannot open the bag ({type(error).__name__}: {error})") from error
        return self

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
        except Exception as error:  # noqa: BLE001 - truncated / corrupt storage
            raise BagError(f"{self.path}: corrupt or truncated bag ({type(error).__name__}: {error})") from error

    def decode(self, message: BagMessage) -> Any:
        """The message as a ``rosbags`` object (types from the bag's embedded definitions)."""
        try:
            return self.reader.deserialize(message.raw, message.msgtype)
        except Exception as error:  # noqa: BLE001 - a message that does not match its type
            raise BagError(f"{self.path}: a {message.msgtype} message on {message.topic} at "
                           f"{message.log_time_ns} ns does not decode ({error})") from error
