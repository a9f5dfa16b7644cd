"""Unfinished bags: ``fiper bag recover PATH...`` finishes them; reading commands read them up to their last
complete chunk (docs/bags.md, "What survives which stop").

A bag is unfinished when it has MCAP data but no ``metadata.yaml`` (a live recording that did not stop
cleanly: ``fiper record`` or ``fiper snapshot`` killed, a power cut), or when an MCAP file it lists does not
end (cut in transfer). Recovering reads every complete, intact chunk of its MCAP files
(:class:`~fiper_ros.bagio.storage.Salvage`) and writes their messages, bit for bit and in file order, into a
new bag with the project's writer: summary, chunk CRCs, ``metadata.yaml`` (``custom_data`` from the old
``metadata.yaml`` if there is one, else from the last MCAP metadata record that holds it: rosbag2's own at
the end of a finished file, or the :data:`~fiper_ros.bagio.writer.INFO_RECORD` a live recorder writes).
``fiper replay``, ``fiper calibrate`` and ``fiper evaluate`` recover an unfinished bag into a temporary
directory (:func:`read_unfinished`) and read that instead, after a one-line warning, unless ``--strict``.
"""
from __future__ import annotations

import os
import tempfile
import warnings
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from mcap.records import Channel, Message, Metadata, Schema
from rosbags.rosbag2.errors import ReaderError
from rosbags.rosbag2.metadata import parse_qos
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from fiper_ros.bagio.atomic import remove, temporary_sibling
from fiper_ros.bagio.errors import BagError
from fiper_ros.bagio.schema import BagInfo
from fiper_ros.bagio.storage import METADATA, Salvage, TruncatedMcap, check_mcap, read_metadata, storage_files
from fiper_ros.bagio.writer import INFO_RECORD, ROSBAG2_KEY, ROSBAG2_RECORD, BagWriter, fsync_directory
from fiper_ros.errors import FiperWarning


def mcap_files(bag: Path) -> list[Path]:
    """The MCAP files of ``bag``: those its ``metadata.yaml`` lists, else every ``*.mcap`` in it."""
    if (bag / METADATA).is_file():
        return storage_files(bag, read_metadata(bag))
    return sorted(bag.glob("*.mcap"))


def unfinished(bag: Path) -> str | None:
    """Why ``bag`` is unfinished (no ``metadata.yaml``, or an MCAP file that does not end), None if it is
    finished; :class:`BagError` if it cannot be read at all (empty or foreign file, bad metadata)."""
    if not (bag / METADATA).is_file():
        return (f"{bag}: MCAP data but no {METADATA}: not a finished rosbag2 bag (the recording did not end, or the "
                "file was removed)")
    for file in mcap_files(bag):
        try:
            check_mcap(file)
        except TruncatedMcap as cut:
            return str(cut)
    return None


@dataclass
class Recovery:
    """What a recovery kept of an unfinished bag."""

    bag: Path
    reason: str
    """Why the bag was unfinished (:func:`unfinished`)."""
    ends: list[str] = field(default_factory=list)
    """Where the reading of each MCAP file stopped before its data end (the cut, or damage)."""
    chunks: int = 0
    counts: Counter[str] = field(default_factory=Counter)
    """Messages kept per topic."""

    @property
    def messages(self) -> int:
        """Messages kept in all."""
        return sum(self.counts.values())

    def where(self) -> str:
        """The reason and where the data ends, without saying the same twice."""
        return "; ".join([self.reason, *(end for end in self.ends if end != self.reason)])


def _definition(schema: Schema, where: str) -> tuple[str, str]:
    """``(msgdef, rihs01)`` of a schema record: the bag's own definition and its type hash."""
    if schema.encoding != "ros2msg":
        raise BagError(f"{where}: schema {schema.name} is encoded as {schema.encoding!r}; recover reads ros2msg")
    msgdef = schema.data.decode()
    store = get_typestore(Stores.EMPTY)
    try:
        store.register(get_types_from_msg(msgdef, schema.name))
        return msgdef, store.hash_rihs01(schema.name)
    except Exception as error:  # a definition rosbags cannot parse is damage
        raise BagError(f"{where}: unreadable definition of {schema.name} ({type(error).__name__}: {error})") from error


def _custom_data(record: Metadata, where: str) -> dict[str, str] | None:
    """The ``custom_data`` a metadata record holds: the recorder's so far, or rosbag2's at the end."""
    if record.name == INFO_RECORD:
        return record.metadata
    try:
        metadata = yaml.safe_load(record.metadata.get(ROSBAG2_KEY, ""))
    except yaml.YAMLError as error:
        raise BagError(f"{where}: unreadable rosbag2 metadata record ({error})") from error
    return metadata.get("custom_data") if isinstance(metadata, dict) else None


def _old_info(bag: Path) -> BagInfo | None:
    """The ``custom_data`` of the bag's ``metadata.yaml``, if it has one."""
    if not (bag / METADATA).is_file():
        return None
    return BagInfo.from_custom_data(read_metadata(bag).get("custom_data"), str(bag))


def recover_bag(bag: Path, out: Path, *, overwrite: bool = False, compress: bool = True) -> Recovery:
    """Write what unfinished ``bag`` holds as the finished bag ``out`` (staged: complete or not there)."""
    reason = unfinished(bag)
    if reason is None:
        raise BagError(f"{bag}: a finished bag, nothing to recover")
    recovery = Recovery(bag, reason)
    info, recorded = _old_info(bag), None
    with BagWriter(out, overwrite=overwrite, compress=compress) as writer:
        for file in mcap_files(bag):
            salvage = Salvage(file)
            schemas: dict[int, Schema] = {}
            channels: dict[int, Channel] = {}
            for record in salvage.records():
                if isinstance(record, Schema):
                    schemas[record.id] = record
                elif isinstance(record, Channel):
                    channels[record.id] = record
                elif isinstance(record, Metadata) and record.name in (INFO_RECORD, ROSBAG2_RECORD):
                    recorded = _custom_data(record, str(file)) or recorded
                elif isinstance(record, Message):
                    channel = channels.get(record.channel_id)
                    if channel is None or channel.schema_id not in schemas:
                        raise BagError(f"{file}: a message on channel {record.channel_id}, which no channel or "
                                       "schema record before it defines")
                    if not writer.has_topic(channel.topic):
                        _add_topic(writer, channel, schemas[channel.schema_id], str(file))
                    writer.write(channel.topic, record.log_time, record.data)
                    recovery.counts[channel.topic] += 1
            recovery.chunks += salvage.chunks
            if salvage.end:
                recovery.ends.append(salvage.end)
        if not recovery.chunks:
            raise BagError(f"{recovery.where()}: no complete chunk, nothing to read")
        writer.info = info if info is not None else BagInfo.from_custom_data(recorded, str(bag))
    return recovery


def _add_topic(writer: BagWriter, channel: Channel, schema: Schema, where: str) -> None:
    msgdef, rihs01 = _definition(schema, where)
    try:
        offered = parse_qos(channel.metadata.get("offered_qos_profiles", ""))
    except (ReaderError, KeyError, TypeError, ValueError) as error:
        raise BagError(f"{where}: unreadable offered QoS of {channel.topic} ({error})") from error
    writer.add_topic(channel.topic, schema.name, offered, msgdef=msgdef, rihs01=rihs01)


def recover_in_place(bag: Path) -> Recovery:
    """Recover ``bag`` into itself: its MCAP file replaced by the recovered one, then ``metadata.yaml`` written
    (a stop in between leaves a bag that recovers again)."""
    staging = temporary_sibling(bag)
    remove(staging)
    staging.mkdir()
    try:
        old = mcap_files(bag)
        recovery = recover_bag(bag, staging / bag.name)
        new = bag / f"{bag.name}.mcap"
        os.replace(staging / bag.name / new.name, new)
        for file in old:
            if file != new:
                file.unlink(missing_ok=True)
        os.replace(staging / bag.name / METADATA, bag / METADATA)
        fsync_directory(bag)
    finally:
        remove(staging)
    return recovery


@dataclass
class _Copy:
    """A recovered copy of an unfinished bag, valid while the bag's files are as they were."""

    directory: tempfile.TemporaryDirectory[str]
    path: Path
    recovery: Recovery
    state: tuple[tuple[str, int, int], ...]


def _state(bag: Path) -> tuple[tuple[str, int, int], ...]:
    """Name, size and modification time of every file of ``bag``."""
    return tuple((f.name, (st := f.stat()).st_size, st.st_mtime_ns) for f in sorted(bag.iterdir()) if f.is_file())


#: Recovered copies of the unfinished bags this process read, by bag (resolved); removed at exit.
_COPIES: dict[Path, _Copy] = {}


def readable_copy(bag: Path) -> Path | None:
    """The recovered copy :func:`read_unfinished` made of ``bag``, while the bag is unfinished (a recording
    that is still being written is read as it was then, by every reader of one command)."""
    copy = _COPIES.get(Path(bag).resolve())
    if copy is None:
        return None
    try:
        return copy.path if unfinished(bag) is not None else None
    except BagError:
        return None  # what the bag is now is refused by its reader


def read_unfinished(bag: Path) -> Recovery:
    """Recover unfinished ``bag`` into a temporary directory (once per state of its files), which
    :class:`~fiper_ros.bagio.reader.BagReader` then reads instead; a :class:`~fiper_ros.errors.FiperWarning` says
    in one line what is read (``fiper COMMAND: warning: ...`` from the CLI)."""
    copy = _COPIES.get(Path(bag).resolve())
    if copy is None or copy.state != _state(bag):
        state = _state(bag)
        directory = tempfile.TemporaryDirectory(prefix="fiper-unfinished-")
        try:
            recovery = recover_bag(bag, Path(directory.name) / bag.name, compress=False)
        except BaseException:
            directory.cleanup()
            raise
        copy = _COPIES[Path(bag).resolve()] = _Copy(directory, Path(directory.name) / bag.name, recovery, state)
    recovery = copy.recovery
    warnings.warn(f"{recovery.where()}: reading its {recovery.chunks} complete chunk(s), {recovery.messages} "
                  f"messages ('fiper bag recover {bag}' finishes the bag)", FiperWarning, stacklevel=3)
    return recovery
