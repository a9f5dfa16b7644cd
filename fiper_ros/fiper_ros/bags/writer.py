"""Writing FIPER bags: rosbag2 format 9, MCAP storage with zstd-compressed chunks, ``custom_data``.

The bag is written under a temporary name beside its target and renamed when :meth:`BagWriter.close`
succeeds; :meth:`BagWriter.abort` (or an exception inside ``with``) removes it, so a reader never sees
a half-written bag. Every chunk carries the CRC-32 of its records (:func:`~fiper_ros.bags.storage.add_chunk_crcs`),
so a reader refuses a bag damaged later instead of decoding other values.
"""
from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from fiper_ros.bags.atomic import check_new, commit, remove, temporary_sibling
from fiper_ros.bags.errors import BagError
from fiper_ros.bags.schema import TOPICS, BagInfo, bag_qos, typestore
from fiper_ros.bags.storage import add_chunk_crcs


class BagWriter:
    """One bag being written; every topic's connection carries its offered QoS.

    Args:
        path: The rosbag2 directory to create (must not exist unless ``overwrite``).
        overwrite: Replace an existing ``path`` at :meth:`close`.
        compress: zstd-compress the MCAP chunks (the bag stays a plain MCAP rosbag2 bag: chunk
            compression is part of MCAP, ``metadata.yaml`` says no file/message compression).
    """

    def __init__(self, path: Path, *, overwrite: bool = False, compress: bool = True) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        check_new(self.path, overwrite)
        # rosbags names the MCAP file after the bag directory: stage as <hidden dir>/<name>, so the
        # finished bag's file is <name>/<name>.mcap whatever the staging name was.
        self._staging = temporary_sibling(self.path)
        remove(self._staging)
        self._staging.mkdir()
        self._temporary = self._staging / self.path.name
        self._writer = Writer(self._temporary, version=9, storage_plugin=StoragePlugin.MCAP)
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._writer.open()
        self._connections: dict[str, Connection] = {}
        self.info = BagInfo()
        self.count = 0

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` has a connection already."""
        return topic in self._connections

    def add_topic(self, topic: str, msgtype: str, offered: Sequence[Qos] = ()) -> None:
        """Add ``topic`` (once); without ``offered`` QoS a schema topic gets the suite's publisher QoS."""
        if topic in self._connections:
            return
        if not offered and topic in TOPICS:
            offered = [bag_qos(TOPICS[topic].qos)]
        store = typestore()
        if msgtype not in store.fielddefs:
            raise BagError(f"{self.path}: no definition of message type {msgtype} to record topic {topic}")
        try:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=store, offered_qos_profiles=list(offered))
        except WriterError as error:
            raise BagError(f"{self.path}: {error}") from error

    def write(self, topic: str, log_time_ns: int, raw: bytes, msgtype: str | None = None) -> None:
        """Write one serialised (CDR) message; a schema topic is added on first use."""
        if topic not in self._connections:
            if msgtype is None:
                if topic not in TOPICS:
                    raise BagError(f"{self.path}: topic {topic} is not in the schema: give its type")
                msgtype = TOPICS[topic].msgtype
            self.add_topic(topic, msgtype)
        self._writer.write(self._connections[topic], int(log_time_ns), raw)
        self.count += 1

    def close(self) -> Path:
        """Store :attr:`info` as ``custom_data``, finish the bag and move it into place."""
        for key, value in self.info.to_custom_data().items():
            self._writer.set_custom_data(key, value)
        try:
            self._writer.close()
            for storage in self._temporary.glob("*.mcap"):
                add_chunk_crcs(storage)
        except (WriterError, OSError) as error:
            self.abort()
            raise BagError(f"{self.path}: could not finish the bag: {error}") from error
        try:
            commit(self._temporary, self.path, self.overwrite)
        finally:
            remove(self._staging)
        return self.path

    def abort(self) -> None:
        """Drop everything written so far."""
        self._writer.abort()
        remove(self._staging)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()
