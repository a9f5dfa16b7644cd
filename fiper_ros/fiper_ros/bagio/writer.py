"""Writing FIPER bags: rosbag2 format 9, MCAP storage with zstd-compressed chunks, ``custom_data``.

The rosbag2 layer (connections, message definitions and their RIHS01 hashes, offered QoS, ``metadata.yaml``)
is ``rosbags``' ``Writer``; its MCAP storage is the ``mcap`` package's writer behind ``rosbags``' storage
interface (:class:`_McapStorage`), which fills in every chunk's CRC-32 (so a reader refuses a bag damaged
later instead of decoding other values) and closes a chunk whenever asked.

Two ways to write (docs/bags.md, "What survives which stop"):

- **Staged** (default): the bag is written under a temporary name beside its target and renamed when
  :meth:`BagWriter.close` succeeds; :meth:`BagWriter.abort` (or an exception inside ``with``) removes it, so
  a reader never sees a half-written bag. Converted bags, ``fiper collect`` and the demo's recording.
- **Live** (``live=LiveChunks(...)``: ``fiper record``, ``fiper snapshot``): the bag lives at its final path
  from the start; a chunk is closed, written and fsync'ed at least every ``seconds`` (:meth:`BagWriter.tick`)
  or ``megabytes`` of messages, so a crash loses at most the open chunk; ``metadata.yaml`` is written at
  :meth:`BagWriter.close`. Until then the bag is unfinished and ``fiper bag recover`` (or any reading command)
  reads its complete chunks; its ``custom_data`` so far goes into an MCAP metadata record
  (:data:`INFO_RECORD`) with every chunk that changes it, so a recovered bag keeps it.
"""
from __future__ import annotations

import contextlib
import os
import time
from collections.abc import Callable, Sequence
from functools import partial
from importlib.metadata import version
from pathlib import Path
from types import TracebackType

from mcap.writer import CompressionType
from mcap.writer import Writer as McapWriter
from rosbags.interfaces import Connection, MessageDefinitionFormat, Qos
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from fiper_ros import __version__
from fiper_ros.bagio.atomic import check_new, commit, remove, temporary_sibling
from fiper_ros.bagio.chunks import DEFAULT_CHUNK_MB, LiveChunks
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.schema import BagInfo, offered_qos, typestore
from fiper_ros.bagio.storage import METADATA
from fiper_ros.interface.topics import topic_spec

#: Name of the MCAP metadata record that holds a live bag's ``custom_data`` so far.
INFO_RECORD = "fiper_custom_data"
#: Name and key of the MCAP metadata record rosbag2 stores its metadata in (as ``ros2 bag`` does).
ROSBAG2_RECORD, ROSBAG2_KEY = "rosbag2", "serialized_metadata"
#: Bytes a message adds to a chunk besides its data (record head, channel id, sequence, two times).
MESSAGE_OVERHEAD = 31


def fsync_directory(path: Path) -> None:
    """Make the entries of directory ``path`` (a new file, a rename) durable."""
    descriptor = os.open(path, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)


class _McapStorage:
    """``rosbags``' MCAP storage interface written by the ``mcap`` package: the file ``<bag>/<bag name>.mcap``.

    A chunk is closed by :meth:`flush` (and when it holds ``chunk_bytes`` of messages); ``durable``: each
    closed chunk is fsync'ed, and so is the directory entry of the new file.
    """

    def __init__(self, path: Path, compression: CompressionMode, *, chunk_bytes: int, durable: bool) -> None:
        self.path = path / f"{path.name}.mcap"
        self._stream = self.path.open("xb")
        self._durable = durable
        self._chunk_bytes = chunk_bytes
        # Chunks are closed here (flush), never by the mcap writer's own size rule.
        self._mcap = McapWriter(self._stream, chunk_size=1 << 62,
                                compression=CompressionType.ZSTD if compression == CompressionMode.STORAGE
                                else CompressionType.NONE)
        self._mcap.start(profile="ros2", library=f"fiper-ros {__version__}, mcap-python {version('mcap')}")
        self._schemas: dict[str, int] = {}
        self._channels: dict[int, int] = {}
        self.open_bytes = 0
        """Message bytes in the open chunk."""
        self.opened_at = 0.0
        """``time.monotonic()`` of the open chunk's first message."""
        if durable:
            self._stream.flush()
            os.fsync(self._stream.fileno())
            fsync_directory(path)
            fsync_directory(path.parent)

    def add_msgtype(self, connection: Connection) -> None:
        """Register the schema of ``connection``'s type."""
        encoding = "ros2msg" if connection.msgdef.format == MessageDefinitionFormat.MSG else "ros2idl"
        self._schemas[connection.msgtype] = self._mcap.register_schema(
            connection.msgtype, encoding, connection.msgdef.data.encode())

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Register ``connection`` as a channel, with its offered QoS as rosbag2 stores them."""
        self._channels[connection.id] = self._mcap.register_channel(
            connection.topic, connection.ext.serialization_format,  # type: ignore[union-attr]
            self._schemas[connection.msgtype], {"offered_qos_profiles": offered_qos_profiles})

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """Add one message to the open chunk; close the chunk once it holds ``chunk_bytes``."""
        if not self.open_bytes:
            self.opened_at = time.monotonic()
        self._mcap.add_message(self._channels[connection.id], timestamp, bytes(data), timestamp)
        self.open_bytes += len(data) + MESSAGE_OVERHEAD
        if self.open_bytes >= self._chunk_bytes:
            self.flush()

    def add_metadata(self, name: str, data: dict[str, str]) -> None:
        """An MCAP metadata record, written at once (outside the open chunk)."""
        self._mcap.add_metadata(name, data)

    def flush(self) -> None:
        """Close the open chunk (if it holds messages) and hand everything to the disk."""
        self._mcap.flush()
        if self._durable:
            os.fsync(self._stream.fileno())
        self.open_bytes = 0

    def close(self, version: int, metadata: str) -> None:
        """Finish the file: the rosbag2 metadata record, the last chunk, the summary and the footer."""
        del version
        self._mcap.add_metadata(ROSBAG2_RECORD, {ROSBAG2_KEY: metadata})
        self._mcap.finish()
        self._stream.flush()
        if self._durable:
            os.fsync(self._stream.fileno())
        self._stream.close()

    def abort(self) -> None:
        """Stop writing: the open chunk is written (a live bag keeps it, unfinished), the file closed."""
        try:
            self.flush()
        finally:
            self._stream.close()


class _Rosbag2Writer(Writer):
    """``rosbags``' rosbag2 writer on :class:`_McapStorage`."""

    def __init__(self, path: Path, storage: Callable[[Path, CompressionMode], _McapStorage]) -> None:
        super().__init__(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.STORAGE_PLUGINS = {StoragePlugin.MCAP: storage}  # type: ignore[misc, dict-item]


class BagWriter:
    """One bag being written; every topic's connection carries its offered QoS.

    Args:
        path: The rosbag2 directory to create (must not exist unless ``overwrite``).
        overwrite: Replace an existing ``path`` (staged: at :meth:`close`; live: at once).
        compress: zstd-compress the MCAP chunks (the bag stays a plain MCAP rosbag2 bag: chunk
            compression is part of MCAP, ``metadata.yaml`` says no file/message compression).
        live: Write at ``path`` from the start, chunks to disk as they go (see the module docstring);
            None: staged.
    """

    def __init__(self, path: Path, *, overwrite: bool = False, compress: bool = True,
                 live: LiveChunks | None = None) -> None:
        self.path = Path(path)
        self.overwrite = overwrite
        self.live = live
        check_new(self.path, overwrite)
        self._staging: Path | None = None
        if live is None:
            # rosbags names the MCAP file after the bag directory: stage as <hidden dir>/<name>, so the
            # finished bag's file is <name>/<name>.mcap whatever the staging name was.
            self._staging = temporary_sibling(self.path)
            remove(self._staging)
            self._staging.mkdir()
            target = self._staging / self.path.name
        else:
            remove(self.path)
            target = self.path
        megabytes = DEFAULT_CHUNK_MB if live is None else live.megabytes
        self._writer = _Rosbag2Writer(target, partial(_McapStorage, chunk_bytes=int(megabytes * 2**20),
                                                      durable=live is not None))
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        try:
            self._writer.open()
        except (WriterError, OSError) as error:
            raise BagError(f"{self.path}: cannot create the bag: {error}") from error
        self._connections: dict[str, Connection] = {}
        self.info = BagInfo()
        self._stored_info: dict[str, str] = {}
        self.count = 0

    @property
    def _storage(self) -> _McapStorage:
        return self._writer.storage  # type: ignore[return-value]

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` has a connection already."""
        return topic in self._connections

    def add_topic(self, topic: str, msgtype: str, offered: Sequence[Qos] = (), *, msgdef: str | None = None,
                  rihs01: str | None = None) -> None:
        """Add ``topic`` (once); without ``offered`` QoS a schema topic gets the suite's publisher QoS.
        The type's definition is the installed one, or ``msgdef`` with its hash ``rihs01`` (both given)."""
        if topic in self._connections:
            return
        if not offered and _in_schema(topic):
            offered = [offered_qos(topic_spec(topic).qos)]
        store = typestore()
        if msgdef is None and msgtype not in store.fielddefs:
            raise BagError(f"{self.path}: no definition of message type {msgtype} to record topic {topic}")
        try:
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=store, msgdef=msgdef, rihs01=rihs01, offered_qos_profiles=list(offered))
        except WriterError as error:
            raise BagError(f"{self.path}: {error}") from error

    def write(self, topic: str, log_time_ns: int, raw: bytes, msgtype: str | None = None) -> None:
        """Write one serialised (CDR) message; a schema topic is added on first use."""
        if topic not in self._connections:
            if msgtype is None:
                if not _in_schema(topic):
                    raise BagError(f"{self.path}: topic {topic} is not in the schema: give its type")
                msgtype = topic_spec(topic).msgtype
            self.add_topic(topic, msgtype)
        try:
            self._writer.write(self._connections[topic], int(log_time_ns), raw)
        except OSError as error:
            raise BagError(f"{self.path}: cannot write: {error}") from error
        self.count += 1

    def tick(self) -> None:
        """Live bag: write the open chunk if it is ``seconds`` old (call it often, e.g. every spin)."""
        storage = self._storage
        if self.live is not None and storage.open_bytes and time.monotonic() - storage.opened_at >= self.live.seconds:
            self.flush()

    def flush(self) -> None:
        """Close the open chunk and hand it to the disk now; a live bag's changed :attr:`info` goes with it."""
        try:
            custom_data = self.info.to_custom_data()
            if self.live is not None and custom_data != self._stored_info:
                self._storage.add_metadata(INFO_RECORD, custom_data)
                self._stored_info = custom_data
            self._storage.flush()
        except OSError as error:
            raise BagError(f"{self.path}: cannot write: {error}") from error

    def close(self) -> Path:
        """Store :attr:`info` as ``custom_data`` and finish the bag (staged: move it into place)."""
        for key, value in self.info.to_custom_data().items():
            self._writer.set_custom_data(key, value)
        try:
            self._writer.close()
            if self.live is not None:
                with (self.path / METADATA).open("rb") as stream:
                    os.fsync(stream.fileno())
                fsync_directory(self.path)
        except (WriterError, OSError) as error:
            self.abort()
            raise BagError(f"{self.path}: could not finish the bag: {error}") from error
        if self._staging is not None:
            try:
                commit(self._staging / self.path.name, self.path, self.overwrite)
            finally:
                remove(self._staging)
        return self.path

    def abort(self) -> None:
        """Stop writing. Staged: drop everything written so far. Live: what was written stays, unfinished
        (with the open chunk), for ``fiper bag recover``."""
        with contextlib.suppress(OSError):  # a full disk: the error that stopped the writing is the one reported
            self._writer.abort()
        if self._staging is not None:
            remove(self._staging)

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, value: BaseException | None,
                 traceback: TracebackType | None) -> None:
        if kind is None:
            self.close()
        else:
            self.abort()


def _in_schema(topic: str) -> bool:
    """Whether ``topic`` is one of the bag schema's (:func:`~fiper_ros.interface.topics.topic_spec`)."""
    try:
        topic_spec(topic)
    except KeyError:
        return False
    return True
